"""A running app (real simulator on loopback, real driver) shared by the REST tests."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from server.app import create_app
from server.settings import Settings

PILOT = "pilot-token-for-tests"
OBSERVER = "observer-token-for-tests"


@pytest.fixture
async def api(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
    settings = Settings(
        data_dir=tmp_path,
        token=PILOT,
        observer_token=OBSERVER,
        sim_base_addr="127.0.0.31",
        sim_speed=4.0,
    )
    app = create_app(settings)
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(
            transport=transport,
            base_url="http://127.0.0.1:8000",
            headers={"Authorization": f"Bearer {PILOT}"},
        ) as client:
            client.app = app  # type: ignore[attr-defined]
            yield client
