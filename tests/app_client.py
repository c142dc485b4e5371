"""The whole app in-process behind an httpx client (its lifespan started), for REST tests."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.app import create_app
from server.settings import Settings
from tests.support.loopback import fresh_address

EMBEDDED: dict[str, Any] = {"vehicles": "inline", "asr_preload": False}
"""An app built in the test process: its flight stacks inline, the speech model loaded on first
use (the defaults of :class:`Settings` are ``serve``'s: vehicle processes, the model at start)."""


def embedded(settings: Settings) -> Settings:
    """``settings`` with :data:`EMBEDDED` where it does not say otherwise."""
    return settings.with_(
        **{k: v for k, v in EMBEDDED.items() if k not in settings.model_fields_set}
    )


@contextlib.asynccontextmanager
async def app_client(settings: Settings) -> AsyncIterator[httpx.AsyncClient]:
    """``create_app(settings)`` (made :func:`embedded`) started, with a client holding the pilot
    token; the app is at ``client.app`` for tests that look at the runtime."""
    app = create_app(embedded(settings))
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(
            transport=transport,
            # No socket: the Host an ASGI transport sends, the console's default address
            # (Settings.host 127.0.0.1, Settings.port 8000).
            base_url="http://127.0.0.1:8000",
            headers={"Authorization": f"Bearer {settings.token}"},
        ) as client:
            client.app = app  # type: ignore[attr-defined]
            yield client


def app_fixture(
    token: str, observer_token: str, **settings: Any
) -> Callable[[Path], AsyncIterator[httpx.AsyncClient]]:
    """A pytest fixture ``api``: :func:`app_client` on simulators of its own (each test gets
    fresh loopback addresses, one per drone of ``fleet``, so tests never share a drone), data
    in the test's tmp_path, ``settings`` passed on to :class:`Settings`. Use:
    ``api = app_fixture(PILOT, OBSERVER, fleet=2)``.
    """

    @pytest.fixture
    async def api(tmp_path: Path) -> AsyncIterator[httpx.AsyncClient]:
        config = Settings(
            data_dir=tmp_path / "data",
            token=token,
            observer_token=observer_token,
            sim_base_addr=fresh_address(max(1, settings.get("fleet", 1))),
            **settings,
        )
        async with app_client(config) as client:
            yield client

    return api  # type: ignore[no-any-return]
