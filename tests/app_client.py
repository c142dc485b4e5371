"""The whole app in-process behind an httpx client (its lifespan started), for REST tests."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

import httpx

from server.app import create_app
from server.settings import Settings


@contextlib.asynccontextmanager
async def app_client(settings: Settings) -> AsyncIterator[httpx.AsyncClient]:
    """``create_app(settings)`` started, with a client holding the pilot token; the app is
    at ``client.app`` for tests that look at the runtime."""
    app = create_app(settings)
    async with app.router.lifespan_context(app):
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(
            transport=transport,
            base_url="http://127.0.0.1:8000",
            headers={"Authorization": f"Bearer {settings.token}"},
        ) as client:
            client.app = app  # type: ignore[attr-defined]
            yield client
