"""Route coverage as the console reports it (``GET /api/v1/patrol``: ``mission.coverage.route``,
the CTM's samples of its drones' reported positions) against the lockstep experiment's own
measure (the simulator's true positions every tick): within 1 percentage point of coverage and
5 s of longest gap, for both handoff rules (the reactive one leaves gaps, so the gap figure is
tested on real gaps)."""

from __future__ import annotations

import pytest

from experiments.patrol import PatrolConfig, PatrolExperiment
from server.fleet.continuity import RouteCoverage

FAST = {"flight_time_s": 150.0, "charge_pct_s": 1.0}
COVERAGE_PP = 1.0  # the tolerance against the lockstep experiment
GAP_S = 5.0


def test_route_coverage_counts_from_the_first_drone_on_the_route() -> None:
    rc = RouteCoverage()
    assert rc.coverage() is None
    rc.sample(False, 0.0)  # flying out: not in the window yet
    rc.sample(False, 5.0)
    assert rc.coverage() is None and rc.window_s() == 0.0
    for t in range(10, 31):  # on the route from t = 10 to 30
        rc.sample(True, float(t))
    for t in (31, 32, 33, 34):  # each interval counts as its later sample says: 30..34 empty
        rc.sample(False, float(t))
    rc.sample(True, 35.0)  # 34..35 covered; the gap runs from the last covered look to here
    rc.sample(True, 40.0)
    assert rc.window_s() == 30.0
    assert rc.covered_s == pytest.approx(26.0)
    assert rc.coverage() == pytest.approx(26.0 / 30.0)
    assert rc.longest() == pytest.approx(5.0)
    d = rc.as_dict(started_t=0.0)
    assert d["gaps"] == 1 and d["first_on_route_s"] == 10.0 and d["longest_gap_s"] == 5.0
    assert d["coverage_pct"] == pytest.approx(86.67, abs=0.01)


def test_an_open_gap_counts_in_the_longest() -> None:
    rc = RouteCoverage()
    rc.sample(True, 0.0)
    rc.sample(True, 1.0)
    rc.sample(False, 2.0)
    rc.sample(False, 9.0)
    assert rc.longest() == pytest.approx(8.0)
    assert rc.as_dict(0.0)["gaps"] == 1
    rc.sample(False, 8.0)  # a sample out of order never counts time backwards
    assert rc.covered_s == pytest.approx(1.0)


@pytest.mark.parametrize("rule", ["reactive", "predictive"])
def test_the_consoles_coverage_matches_the_experiments(rule: str) -> None:
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=400.0, handoff=rule, **FAST))
    report = exp.run()
    assert report.handoffs >= 2
    if rule == "reactive":
        assert report.max_gap_s > 2.0, report.gaps  # real gaps to measure
    mid = next(iter(exp.ctm.missions))
    route = exp.ctm.mission_info(mid, exp.rig.clock.now())["coverage"]["route"]
    assert abs(route["coverage_pct"] - 100.0 * report.coverage) <= COVERAGE_PP, (route, report)
    assert abs(route["longest_gap_s"] - report.max_gap_s) <= GAP_S, (route, report.gaps)
    assert route["first_on_route_s"] == pytest.approx(report.first_on_route_s, abs=2.0)
    assert abs(route["gaps"] - len(report.gaps)) <= 1, (route, report.gaps)
