"""Closed-loop fleet tests in lockstep: the real simulator, wire protocol, EKF, PID, task
manager, LTMs and CTM, with a fast battery (flight time 150 s) so a shift lasts ~1.5 minutes."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from experiments.patrol import PatrolConfig, PatrolExperiment, patrol_main
from server import cli
from server.fleet.messages import DroneRole

FAST = {"flight_time_s": 150.0, "swap_s": 20.0}
# Stated bound on any coverage gap at a handoff: none may exceed one tick of the rig, since the
# relief is on the route before the tired drone is sent home.
HANDOFF_GAP_BOUND_S = 0.5


@pytest.fixture(scope="module")
def two_drones() -> tuple[PatrolExperiment, object, list[tuple[float, str, float]]]:
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=260.0, **FAST))
    seen: list[tuple[float, str, float]] = []
    done: set[float] = set()

    def watch(now: float) -> None:  # (t, name, battery) of the drone sent home at each handoff
        for t, text in exp.ctm.events:
            if "relieves" in text and t not in done:
                done.add(t)
                old = text.split("relieves ")[1].split(" ")[0]
                seen.append((t, old, exp.rig.sims[int(old[3:]) - 1].truth.battery_pct))

    exp.hooks.append(watch)
    report = exp.run()
    return exp, report, seen


def test_handoff_at_threshold_without_gap(two_drones) -> None:
    exp, report, seen = two_drones
    assert report.handoffs >= 2
    assert report.first_on_route_s is not None and report.first_on_route_s < 30
    assert report.max_gap_s <= HANDOFF_GAP_BOUND_S, report.gaps
    assert report.coverage >= 0.995
    assert len(seen) == report.handoffs
    m = exp.model
    lead = m.takeoff_s + 22.0 / m.speed_m_s + 5.0 / m.climb_m_s + m.margin_s
    for _, _, battery in seen:
        # relieved at the 30 % threshold plus at most the lead time's drain: the relief was
        # dispatched for the threshold and arrived early, never after the drone had to leave
        assert 30.0 - 2.0 <= battery <= 30.0 + lead * m.drain_pct_s, seen


def test_tired_drone_lands_at_station_and_recharges(two_drones) -> None:
    exp, report, seen = two_drones
    first_home = seen[0][1]
    i = int(first_home[3:]) - 1
    rows = report.tracks[first_home]
    t_handoff = seen[0][0] - exp.rig.clock.now() + report.duration_s  # relative time
    after = [r for r in rows if r[0] > t_handoff]
    landed = [r for r in after if r[3] < 0.05]
    assert landed, "the relieved drone never landed"
    station = exp.stations[i].position
    x, y = landed[0][1], landed[0][2]
    assert math.hypot(x - station.x, y - station.y) < 1.0
    assert exp.stations[i].restores >= 1
    assert max(r[4] for r in after) >= 99.0  # battery swapped
    roles = {r[5] for r in after}
    assert {"returning", "charging"} <= roles


def test_failed_drone_is_replaced() -> None:
    exp = PatrolExperiment(PatrolConfig(drones=3, duration_s=120.0, fail_at_s=50.0, **FAST))
    report = exp.run()
    assert report.replacements == 1
    lost = [r for r in exp.ctm.drones.values() if r.role is DroneRole.LOST]
    assert len(lost) == 1 and lost[0].lost_reason == "emergency"
    # the gap is bounded by detection + take-off + transit of the replacement
    lead = exp.model.takeoff_s + 30.0 / exp.model.speed_m_s + 15.0
    assert 0 < report.max_gap_s < lead
    assert report.coverage > 0.75


def test_ltm_disconnect_and_reconnect() -> None:
    """The active drone's LTM loses the CTM for 30 s: the CTM marks it lost and sends a
    replacement; the LTM flies home on its own; on reconnect the CTM sees it back."""
    cfg = PatrolConfig(drones=2, duration_s=110.0, ctm_timeout_s=8.0, **FAST)
    exp = PatrolExperiment(cfg)
    state: dict[str, object] = {}

    def cut(now: float) -> None:
        ms = next(iter(exp.ctm.missions.values()), None)
        if "victim" not in state and ms is not None and ms.active and now > 30.0:
            state["victim"] = ms.active
            state["t"] = now
            exp.link.connected[ms.active] = False
        if "victim" in state and "back" not in state and now > float(state["t"]) + 30.0:
            exp.link.connected[str(state["victim"])] = True
            state["back"] = now
        if "victim" in state and "back" not in state:
            v = str(state["victim"])
            state.setdefault("roles", set()).add(exp.ctm.drones[v].role)  # type: ignore[union-attr]
            auto = exp.ltms[int(v[3:]) - 1].autonomous
            if auto:
                state["autonomous"] = auto

    exp.hooks.append(cut)
    report = exp.run()
    victim = str(state["victim"])
    assert DroneRole.LOST in state["roles"]  # type: ignore[operator]
    assert state.get("autonomous") == "ctm_silent"
    assert report.replacements == 1
    rec = exp.ctm.drones[victim]
    assert rec.role is not DroneRole.LOST  # heard again
    assert any(f"{victim} back" in text for _, text in exp.ctm.events)
    assert report.max_gap_s < 25.0


def test_cli_json_and_png(tmp_path, capsys) -> None:
    png = tmp_path / "patrol.png"
    rc = patrol_main(["--drones", "1", "--duration", "30", "--json", "--png", str(png)])
    assert rc == 0

    def no_nan(c: str) -> None:
        raise ValueError(f"{c} is not JSON")

    out = json.loads(capsys.readouterr().out, parse_constant=no_nan)
    for key in ("coverage", "max_gap_s", "handoffs", "drones", "duration_s"):
        assert key in out
    assert 0.0 <= out["coverage"] <= 1.0 and out["drones"] == 1 and out["duration_s"] == 30
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    ("argv", "msg"),
    [
        (["--threshold", "1.5"], "threshold"),
        (["--drones", "0"], "drones"),
        (["--drones", "17"], "drones"),
    ],
)
def test_cli_bad_arguments(argv: list[str], msg: str, capsys) -> None:
    assert patrol_main(argv) == 2
    assert msg in capsys.readouterr().err


def test_patrol_command_without_the_experiment_says_so(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An install without the checkout's ``experiments/`` (the wheel): a clear error, status 2."""
    for name in [m for m in sys.modules if m.split(".")[0] == "experiments"]:
        monkeypatch.setitem(sys.modules, name, None)  # the import fails as if absent
    monkeypatch.setattr(cli, "ROOT", tmp_path)  # no checkout beside the package
    assert cli.main(["patrol", "--drones", "1", "--duration", "5"]) == 2
    err = capsys.readouterr().err
    assert "the patrol experiment is not installed" in err and "source checkout" in err


def test_patrol_command_finds_the_experiment_in_the_checkout(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An installed ``uav-console`` (editable: only ``server`` and ``drone`` on its path) runs
    the experiment from the checkout it was installed from."""
    root = Path(cli.ROOT).resolve()
    for name in [m for m in sys.modules if m.split(".")[0] == "experiments"]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setattr(
        sys, "path", [p for p in sys.path if p not in ("", ".") and Path(p).resolve() != root]
    )
    assert cli.main(["patrol", "--drones", "1", "--duration", "5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["duration_s"] == 5
    assert str(root) in sys.path
