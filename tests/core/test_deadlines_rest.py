"""Deadlines at the REST door with the drone in the web process (``--vehicles inline``): a late
take-off, sentence or mission is answered ``accepted: false`` and audited; a stop is never held
back, not even by a stamp that is not Unix seconds. (The same through a vehicle process:
tests/isolation/test_deadlines.py.)"""

from __future__ import annotations

import re
import time

import httpx

from tests.support.polling import until_async


def _expired(client: httpx.AsyncClient) -> list[str]:
    audit = client.app.state.runtime.audit  # type: ignore[attr-defined]
    return [e.outcome for e in audit.recent(50) if e.action == "expired"]


async def test_late_rest_commands_are_not_flown_and_a_stop_is_never_held_back(
    api: httpx.AsyncClient,
) -> None:
    late = f"{time.time() - 5.0:.3f}"
    r = await api.post("/api/v1/drones/uav1/takeoff", headers={"X-Command-Issued": late})
    assert r.status_code == 200 and r.json()["accepted"] is False, r.text
    # at least 5 s late; how much more depends on the machine's load, not on the rule
    said = re.fullmatch(
        r"Not flown: 'take off' reached the drone (\d+\.\d) s after you gave it \(deadline 2 s\)\.",
        r.json()["detail"],
    )
    assert said is not None and float(said.group(1)) >= 5.0, r.json()["detail"]
    r = await api.post("/api/v1/command", json={"text": "take off", "issued": time.time() - 5})
    assert r.json()["accepted"] is False and r.json()["reply"].startswith("Not flown")
    r = await api.post(
        "/api/v1/missions", json={"markers": [1, 2]}, headers={"X-Command-Issued": late}
    )
    assert r.status_code == 409 and r.json()["accepted"] is False and r.json()["expired"], r.text
    # the rows are written on the audit log's own writer thread, after the answers
    rows = await until_async(
        lambda: len(_expired(api)) == 3 and _expired(api), 10.0, "three expired audit rows"
    )
    assert all(o.startswith("expired: delivered 5.") for o in rows), rows
    # a stamp that is not Unix seconds: a take-off is refused, a stop goes through
    r = await api.post("/api/v1/drones/uav1/takeoff", headers={"X-Command-Issued": "soon"})
    assert r.status_code == 422 and "Unix seconds" in r.text
    r = await api.post("/api/v1/drones/uav1/land", headers={"X-Command-Issued": "soon"})
    assert r.status_code == 200 and r.json()["accepted"] is True, r.text
    r = await api.post("/api/v1/command", json={"text": "land", "issued": -1})
    assert r.status_code == 200, r.text
    # in time, and a script that says nothing: flown
    r = await api.post("/api/v1/drones/uav1/takeoff", json={"issued": time.time()})
    assert r.json()["accepted"] is True, r.text
    r = await api.post("/api/v1/drones/uav1/land")
    assert r.json()["accepted"] is True
