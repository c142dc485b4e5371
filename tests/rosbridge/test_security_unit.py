"""server.http.security without sockets: tokens on disk, roles, the lease, Origin, REST
dependency."""

from __future__ import annotations

import asyncio
import os
import stat
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi import Depends, FastAPI

from server.graph import Graph
from server.http.security import LeaseHeld, PilotLease, Role, Security, TokenStore, require_role
from server.rosbridge.context import BridgeContext
from server.rosbridge.endpoint import serve_rosbridge_port
from server.settings import Settings
from tests.support.loopback import free_port

from .wsclient import RawClient


def test_tokens_created_once_with_0600(tmp_path: Path) -> None:
    first = TokenStore(tmp_path)
    mode = stat.S_IMODE(os.stat(tmp_path / "tokens.json").st_mode)
    assert mode == 0o600
    again = TokenStore(tmp_path)
    assert (again.pilot_token, again.observer_token) == (first.pilot_token, first.observer_token)
    assert first.pilot_token != first.observer_token and len(first.pilot_token) >= 24
    given = TokenStore(tmp_path, pilot_token="my-pilot")
    assert given.role_for("my-pilot") is Role.PILOT
    assert given.role_for(first.observer_token) is Role.OBSERVER
    assert given.role_for("") is None and given.role_for(None) is None
    assert given.role_for("my-pilot ") is None
    with pytest.raises(ValueError, match="must differ"):
        TokenStore(tmp_path, pilot_token="same", observer_token="same")


def test_roles_and_control_names(tmp_path: Path) -> None:
    sec = Security(Settings(data_dir=tmp_path), TokenStore(tmp_path))
    for topic in (
        "/cmd_vel",
        "cmd_vel",
        "/ardrone/takeoff",
        "/uav3/cmd_vel",
        "/uav2/console/utterance",
        "/console/utterance",
    ):
        assert sec.is_control_topic(topic), topic
    for topic in ("/console/reply", "/uav/pose", "/cmd_vel2"):
        assert not sec.is_control_topic(topic), topic
    assert sec.can_publish(Role.PILOT, "/cmd_vel") and not sec.can_publish(Role.OBSERVER, "/x")
    assert sec.can_call(Role.OBSERVER, "rosapi/topics")
    assert sec.can_call(Role.OBSERVER, "/console/interpret")
    assert not sec.can_call(Role.OBSERVER, "/rosapi/set_param")
    assert not sec.can_call(Role.OBSERVER, "/uav1/takeoff")
    assert not sec.can_call(None, "/rosapi/topics")
    assert sec.refusal(Role.OBSERVER, "publish to", "/cmd_vel") == (
        "observer may not publish to /cmd_vel"
    )


def test_lease_takeover_is_explicit_and_told() -> None:
    lease = PilotLease()
    told: list[str] = []
    assert lease.acquire("a", 1.0, on_revoke=told.append)
    assert lease.acquire("a", 2.0)  # re-acquiring keeps the start time
    assert lease.state.since == 1.0
    with pytest.raises(LeaseHeld, match="take over explicitly"):
        lease.acquire("b", 3.0)
    assert lease.acquire("b", 4.0, take_over=True) and told == ["b"]
    assert lease.holds("b") and not lease.holds("a")
    lease.release("a")  # not the holder: no effect
    assert lease.holds("b")
    lease.release("b")
    assert lease.state.holder is None


# Origin and Host headers, parsed, never bound: 8000 is Settings.port's default.
@pytest.mark.parametrize(
    ("origin", "host", "ok"),
    [
        (None, "127.0.0.1:8000", True),
        ("http://127.0.0.1:8000", "127.0.0.1:8000", True),
        ("http://localhost:8123", "localhost:8123", True),
        ("http://LOCALHOST:8123", "localhost:8123", True),
        ("http://evil.example", "127.0.0.1:8000", False),
        ("http://127.0.0.1:9999", "127.0.0.1:8000", False),
        ("null", "127.0.0.1:8000", False),
        ("https://console.example", "127.0.0.1:8000", True),  # allowed by setting
        ("file://", "127.0.0.1:8000", False),
    ],
)
def test_origin(tmp_path: Path, origin: str | None, host: str, ok: bool) -> None:
    settings = Settings(data_dir=tmp_path, allow_origins=("https://console.example",))
    sec = Security(settings, TokenStore(tmp_path))
    assert sec.origin_allowed(origin, host) is ok


async def test_require_role_dependency(tmp_path: Path) -> None:
    sec = Security(Settings(data_dir=tmp_path), TokenStore(tmp_path, pilot_token="p"))
    app = FastAPI()
    pilot_only = Depends(require_role(sec, Role.PILOT))
    anyone = Depends(require_role(sec))

    @app.post("/fly")
    async def fly(role: Role = pilot_only) -> dict[str, Any]:
        return {"role": role.value}

    @app.get("/look")
    async def look(role: Role = anyone) -> dict[str, Any]:
        return {"role": role.value}

    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://t") as http:
        assert (await http.post("/fly")).status_code == 401
        r = await http.post("/fly", headers={"Authorization": "Bearer p"})
        assert r.json() == {"role": "pilot"}
        obs = sec.tokens.observer_token
        r = await http.post("/fly", headers={"Authorization": f"Bearer {obs}"})
        assert r.status_code == 403 and r.json()["detail"] == "observer may not POST /fly"
        assert (await http.get(f"/look?token={obs}")).json() == {"role": "observer"}


async def test_serve_rosbridge_port(tmp_path: Path) -> None:
    """The same protocol on its own port, at / (where clients expecting 9090 connect)."""
    settings = Settings(data_dir=tmp_path)
    tokens = TokenStore(tmp_path)
    ctx = BridgeContext(graph=Graph(), security=Security(settings, tokens), settings=settings)
    port = free_port()
    started = asyncio.Event()
    task = asyncio.create_task(serve_rosbridge_port("127.0.0.1", port, ctx, started=started.set))
    try:
        await asyncio.wait_for(started.wait(), 10)
        url = f"ws://127.0.0.1:{port}/?token={tokens.observer_token}"
        async with await RawClient.open(url) as c:
            await c.send({"op": "call_service", "id": "1", "service": "rosapi/services"})
            r = await c.expect_op("service_response", id="1")
            assert "/rosapi/services" in r["values"]["services"]
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task


def test_generated_tokens_never_look_like_a_command_line_option() -> None:
    from server.http.security import new_token

    tokens = {new_token() for _ in range(2000)}
    assert len(tokens) == 2000
    assert not any(t.startswith("-") for t in tokens)
