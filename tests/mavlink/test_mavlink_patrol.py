"""The persistent patrol with predictive battery handoff flown by simulated PX4 quadrotors over
the outdoor world's GPS waypoints, in lockstep (real MAVLink 2 frames in memory, the autopilot's
own position controller, the task manager, LTMs and the CTM), with a fast battery (150 s)."""

from __future__ import annotations

import math

from experiments.patrol import PatrolConfig, PatrolExperiment


def test_mavlink_fleet_patrol_hands_off_without_gap() -> None:
    cfg = PatrolConfig(
        drones=2, duration_s=170.0, flight_time_s=150.0, swap_s=20.0, protocol="mavlink"
    )
    exp = PatrolExperiment(cfg)
    report = exp.run()
    assert report.first_on_route_s is not None and report.first_on_route_s < 20
    assert report.handoffs >= 1
    assert report.coverage >= 0.99 and report.max_gap_s <= 0.5, report.gaps
    # the relieved drone flew its RTL home, landed on its own pad and got a fresh battery
    homed = [i for i, st in enumerate(exp.stations) if st.restores >= 1]
    assert homed, "no drone came home and was restored"
    i = homed[0]
    pad = exp.stations[i].position
    rows = report.tracks[f"uav{i + 1}"]  # (t, x, y, z, battery, role) each second
    flew = next(r[0] for r in rows if r[3] > 2.0)
    landed = [r for r in rows if r[0] > flew and r[3] < 0.05]
    assert landed and math.hypot(landed[0][1] - pad.x, landed[0][2] - pad.y) < 1.0
    assert all(v.protocol.telemetry.autopilot == "PX4" for v in exp.rig.vehicles)


def test_link_lost_mid_mission_autopilot_returns_and_is_replaced() -> None:
    cfg = PatrolConfig(
        drones=2,
        duration_s=85.0,
        fail_at_s=30.0,
        fail_kind="link",  # the patrolling drone's link drops for 60 s
        flight_time_s=150.0,
        swap_s=20.0,
        protocol="mavlink",
    )
    exp = PatrolExperiment(cfg)
    report = exp.run()
    assert report.replacements == 1
    failed = [
        ap for ap in exp.rig.sims if "Failsafe: no connection to GCS, returning" in ap.statustexts
    ]
    assert len(failed) == 1  # PX4's own data-link failsafe (NAV_DLL_ACT 2) flew it home
    ap = failed[0]
    assert not ap.armed and ap.physics.body.z == 0.0
    assert math.hypot(ap.physics.body.x - ap.home[0], ap.physics.body.y - ap.home[1]) < 0.6
    assert report.coverage > 0.75


def test_patrol_cli_with_mavlink_drones(capsys: object) -> None:
    import json

    from experiments.patrol import patrol_main

    assert (
        patrol_main(["--drones", "1", "--duration", "30", "--protocol", "mavlink", "--json"]) == 0
    )
    out = json.loads(capsys.readouterr().out)  # type: ignore[attr-defined]
    assert out["drones"] == 1 and out["duration_s"] == 30.0
    assert out["coverage"] > 0.9  # on the route within seconds, and it stays there
