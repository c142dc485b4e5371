"""Issue 14's findings at the HTTP door, each reproduced first (a simulator of its own).

| finding                                         | answer now                                   |
|-------------------------------------------------|----------------------------------------------|
| a 400 MB POST without a token                   | 413 before the body is read (no 401 parse)   |
| a chunked body past the route's limit           | 413                                          |
| ``Host: 127.0.0.1:abc``                         | 400 "malformed Host header"                  |
| ``Host: evil.example`` (DNS rebinding)          | 421                                          |
| NaN / Infinity in a REST body                   | 422                                          |
| a lone surrogate in a REST body                 | 422 naming the field; nothing flies          |
| ``wind_mps: [1e308, 1e308]``                    | 422                                          |
| ``"go forward -5 meters"``                      | no command: it is not flown forward          |
| a mission or a fault while another pilot leads  | 409; stopping a mission is allowed           |
| the console's first load with ``?token=``       | HttpOnly SameSite=Strict cookie; CSP et al.  |
"""

from __future__ import annotations

import os
import stat
from collections.abc import AsyncIterator
from pathlib import Path

import httpx
import pytest

from server.http.security import TOKEN_COOKIE, TokenStore
from server.store import AuditLog
from tests.app_client import app_fixture
from tests.support.polling import until_async

PILOT = "pilot-token-for-hardening"
OBSERVER = "observer-token-for-hardening"


api = app_fixture(PILOT, OBSERVER, sim_speed=4.0)


async def test_body_limits_come_before_the_token(api: httpx.AsyncClient) -> None:
    read: list[int] = []

    async def body() -> AsyncIterator[bytes]:
        for _ in range(40):
            read.append(1)
            yield b"x" * 10_000

    r = await api.post(
        "/api/v1/command",
        content=b"{}",
        headers={"Authorization": "", "Content-Length": "400000000"},
    )
    assert r.status_code == 413 and "limit of 65536 bytes" in r.json()["detail"]
    r = await api.post("/api/v1/command", content=body(), headers={"Authorization": ""})
    assert r.status_code == 413
    assert len(read) < 40  # cut off at the limit, not read to the end
    assert (await api.post("/api/v1/command", json={"text": "hello"})).status_code == 200


# Host headers are parsed, never bound: 8000 is Settings.port's default.
@pytest.mark.parametrize(
    ("host", "status"),
    [("127.0.0.1:abc", 400), ("evil.example:8000", 421), ("127.0.0.1:8000.evil", 400)],
)
async def test_bad_host_headers(api: httpx.AsyncClient, host: str, status: int) -> None:
    r = await api.get("/api/v1/health", headers={"Host": host})
    assert r.status_code == status, r.text
    assert "Host" in r.json()["detail"] or "host name" in r.json()["detail"]


async def test_good_host_names(api: httpx.AsyncClient) -> None:
    # single-label names resolve only locally (hosts file, search domain): not an attacker's DNS
    for host in ("localhost:8000", "127.0.0.1", "[::1]:8000", "10.1.2.3:8000", "testserver"):
        assert (await api.get("/api/v1/health", headers={"Host": host})).status_code == 200


@pytest.mark.parametrize(
    ("path", "body", "where"),
    [
        ("/api/v1/command", '{"text": "land", "confidence": NaN}', "confidence"),
        ("/api/v1/command", '{"text": "land", "confidence": Infinity}', "confidence"),
        ("/api/v1/command", '{"text": "take off \\ud800"}', "text"),
        ("/api/v1/interpret", '{"text": "\\udfff take off"}', "text"),
        ("/api/v1/sim/uav1/fault", '{"kind": "wind", "wind_mps": [1e308, 1e308]}', "wind_mps"),
        ("/api/v1/sim/uav1/fault", '{"kind": "battery", "battery_pct": NaN}', "battery_pct"),
        ("/api/v1/missions", '{"markers": [1], "altitude_m": NaN}', "altitude_m"),
    ],
)
async def test_bad_bodies_get_422(api: httpx.AsyncClient, path: str, body: str, where: str) -> None:
    runtime = api.app.state.runtime  # type: ignore[attr-defined]

    def operator_rows() -> list[tuple[str, str]]:  # (the ANS may log its own rows meanwhile)
        return [(e.action, e.outcome) for e in runtime.audit.recent(1000) if e.source != "ans"]

    before = len(operator_rows())
    r = await api.post(path, content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert where in r.text
    # nothing was acted on: at most the audit's intent and its "HTTP 422" outcome
    new = operator_rows()[: len(operator_rows()) - before]
    assert all(outcome in ("pending", "HTTP 422") for _, outcome in new), new


async def test_negative_distance_is_not_flown(api: httpx.AsyncClient) -> None:
    r = await api.post("/api/v1/interpret", json={"text": "go forward -5 meters"})
    assert r.json()["commands"] == []
    r = await api.post("/api/v1/command", json={"text": "go forward -5 meters"})
    assert r.status_code == 200 and r.json()["accepted"] is False
    assert r.json()["commands"] == []
    assert "negative distances" in r.json()["reply"]


async def test_missions_and_faults_need_the_lease_but_stopping_does_not(
    api: httpx.AsyncClient,
) -> None:
    runtime = api.app.state.runtime  # type: ignore[attr-defined]
    runtime.security.lease.acquire("browser-pilot", 0.0)
    route = {"markers": [1, 4], "altitude_m": 1.4}
    assert (await api.post("/api/v1/missions", json=route)).status_code == 409
    fault = {"kind": "wind", "wind_mps": [1.0, 0.0]}
    assert (await api.post("/api/v1/sim/uav1/fault", json=fault)).status_code == 409
    # any pilot may stop (404 here: no such mission, but not refused for the lease)
    assert (await api.delete("/api/v1/missions/m1")).status_code == 404
    key = runtime.security.lease.key_of("browser-pilot")
    made = await api.post("/api/v1/missions", json=route, headers={"X-Pilot-Lease": key})
    assert made.status_code == 201
    stopped = await api.delete(f"/api/v1/missions/{made.json()['id']}")
    assert stopped.status_code == 200 and stopped.json()["state"] == "ended"
    ok = await api.post("/api/v1/sim/uav1/fault", json=fault, headers={"X-Pilot-Lease": key})
    assert ok.status_code == 200


async def test_security_headers_and_token_cookie(api: httpx.AsyncClient) -> None:
    page = await api.get(f"/?token={PILOT}", headers={"Authorization": ""})
    assert page.status_code == 200
    csp = page.headers["content-security-policy"]
    assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp
    assert page.headers["referrer-policy"] == "no-referrer"
    assert page.headers["x-frame-options"] == "DENY"
    cookie = page.headers["set-cookie"]
    assert cookie.startswith(f"{TOKEN_COOKIE}={PILOT};")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    # the cookie alone (no token in the URL or a header) is enough afterwards
    cookie_only = {"Authorization": "", "Cookie": f"{TOKEN_COOKIE}={PILOT}"}
    r = await api.get("/api/v1/drones", headers=cookie_only)
    assert r.status_code == 200
    # a wrong token sets nothing; every API answer carries the headers too
    bad = await api.get("/?token=wrong", headers={"Authorization": ""})
    assert "set-cookie" not in bad.headers
    health = await api.get("/api/v1/health")
    assert health.headers["x-content-type-options"] == "nosniff"


def test_token_file_is_private_and_atomic(tmp_path: Path) -> None:
    data = tmp_path / "fresh" / "uav-console"
    store = TokenStore(data)
    assert stat.S_IMODE(os.stat(data).st_mode) == 0o700
    assert stat.S_IMODE(os.stat(store.path).st_mode) == 0o600
    assert sorted(os.listdir(data)) == ["tokens.json"]  # no temporary file left behind
    # a torn or corrupt file is replaced whole, and a loose directory is tightened
    store.path.write_text('{"pilot": "abc')
    os.chmod(data, 0o755)
    again = TokenStore(data)
    assert again.pilot_token != "abc" and len(again.pilot_token) > 20
    assert stat.S_IMODE(os.stat(data).st_mode) == 0o700
    assert TokenStore(data).pilot_token == again.pilot_token


async def test_mission_names_and_sizes(api: httpx.AsyncClient) -> None:
    route = {"markers": [1, 4], "altitude_m": 1.4}
    r = await api.post("/api/v1/missions", json={**route, "name": "a/b"})
    assert r.status_code == 422 and "name" in r.text
    r = await api.post("/api/v1/missions", json={**route, "name": "x" * 100_000})
    assert r.status_code == 413  # over the body limit: never parsed
    r = await api.post("/api/v1/missions", json={**route, "markers": [1] * 201})
    assert r.status_code == 422
    made = await api.post("/api/v1/missions", json={**route, "name": "north-loop"})
    assert made.status_code == 201
    assert (await api.delete("/api/v1/missions/north-loop")).status_code == 200


async def test_direct_actions_write_intent_then_outcome(api: httpx.AsyncClient) -> None:
    runtime = api.app.state.runtime  # type: ignore[attr-defined]

    def rows() -> list[tuple[str, str, str]]:
        return [
            (e.action, e.outcome, e.utterance)
            for e in reversed(runtime.audit.recent(1000))
            if e.source in ("rest", "lease")
            and e.action.startswith(("intent:", "outcome:", "lease"))
        ]

    assert (await api.post("/api/v1/drones/uav1/reset")).status_code == 200
    (intent, i_out, i_detail), (outcome, o_out, o_detail) = rows()[-2:]
    assert (intent, i_out, i_detail) == (
        "intent:reset",
        "pending",
        "POST /api/v1/drones/uav1/reset",
    )
    assert (outcome, o_out) == ("outcome:reset", "HTTP 200")
    iid = next(e.id for e in runtime.audit.recent(10) if e.action == "intent:reset")
    assert o_detail == f"intent #{iid}"
    # emergency acts first; both rows follow, the intent stamped when the request arrived
    assert (await api.post("/api/v1/drones/uav1/emergency")).status_code == 200
    assert [r[0] for r in rows()[-2:]] == ["intent:emergency", "outcome:emergency"]
    # a refused (no token) request and an observer's leave no row
    n = len(rows())
    assert (
        await api.post("/api/v1/drones/uav1/takeoff", headers={"Authorization": ""})
    ).status_code == 401
    obs = {"Authorization": f"Bearer {OBSERVER}"}
    assert (await api.post("/api/v1/drones/uav1/takeoff", headers=obs)).status_code == 403
    assert len(rows()) == n
    # a lease change is a row; a REST take-over writes its intent, the change and the outcome
    runtime.security.lease.acquire("browser-pilot", 0.0)
    assert (await api.post("/api/v1/drones/uav1/reset?take_over=true")).status_code == 200
    await until_async(  # the lease rows are written off the loop
        lambda: sum(r[0].startswith("lease:") for r in rows()) >= 2, 10.0, "two lease rows"
    )
    actions = [r[0] for r in rows()[n:]]
    assert "lease:acquire" in actions and "lease:take_over" in actions
    assert actions[-1] == "outcome:reset"


def test_audit_log_keeps_lone_surrogates(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "audit.db")
    log.append(utterance="take off \ud800", commands=[], action="executed", outcome="ok")
    assert log.recent(1)[0].utterance == "take off \\ud800"
    log.close()


# Deeply nested JSON (50 000 levels: Python's JSON reader raises RecursionError) is a 400, never
# a 500 (the fuzz campaign found the speech stream's text frames fell to it).
DEEP = b"[" * 50_000

ROUTES = [
    "/api/v1/command",
    "/api/v1/interpret",
    "/api/v1/missions",
    "/api/v1/sim/uav1/fault",
]


@pytest.mark.parametrize("path", ROUTES)
async def test_deep_json_is_a_client_error(api: httpx.AsyncClient, path: str) -> None:
    r = await api.post(path, content=DEEP, headers={"Content-Type": "application/json"})
    assert r.status_code == 400, (r.status_code, r.text[:200])
    assert "error parsing the body" in r.json()["detail"]
