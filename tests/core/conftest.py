"""A running app (real simulator on loopback, real driver) shared by the REST tests."""

from __future__ import annotations

from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from server.settings import Settings
from tests.app_client import app_client

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
    async with app_client(settings) as client:
        yield client
