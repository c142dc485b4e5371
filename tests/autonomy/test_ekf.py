"""The EKF: consistency (NEES), late fixes, gating, Joseph form, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drone.perception.ekf import (
    IX,
    IYAW,
    EkfConfig,
    ExtendedKalmanFilter,
    MarkerFix,
    NavdataInput,
    wrap,
)
from drone.perception.errors import EstimatorError

CHI2_4_95 = (0.484, 11.143)  # χ²(4) 2.5 % and 97.5 % quantiles


def _truth_run(seed: int, seconds: float = 20.0, nav_hz: float = 15.0, fix_every: int = 3):
    """Synthetic flight drawn from the filter's own model; yields events and truth."""
    cfg = EkfConfig()
    rng = np.random.default_rng(seed)
    dt = 1.0 / nav_hz
    x = np.array([2.0, 3.0, 1.0, 0.3, 0.0, 0.0, 0.0])
    omega = 0.0
    out = []
    for k in range(int(seconds * nav_hz)):
        t = (k + 1) * dt
        acc = rng.normal(0, [cfg.accel_sigma_xy, cfg.accel_sigma_xy, cfg.accel_sigma_z])
        x[0:3] += x[4:7] * dt + 0.5 * acc * dt * dt
        x[4:7] += acc * dt
        omega = 0.8 * math.sin(0.4 * t)
        x[3] = wrap(x[3] + omega * dt + rng.normal(0, cfg.yaw_rate_sigma * dt))
        c, s = math.cos(x[3]), math.sin(x[3])
        vb = (c * x[4] + s * x[5], -s * x[4] + c * x[5])
        nav = NavdataInput(
            t,
            vb[0] + rng.normal(0, cfg.vel_sigma),
            vb[1] + rng.normal(0, cfg.vel_sigma),
            x[6] + rng.normal(0, cfg.vz_sigma),
            x[2] + rng.normal(0, cfg.alt_sigma),
            omega,
        )
        fix = None
        if k % fix_every == 0:
            R = np.diag([0.03**2, 0.03**2, 0.03**2, math.radians(1.5) ** 2])
            n = rng.multivariate_normal(np.zeros(4), R)
            fix = MarkerFix(t, x[0] + n[0], x[1] + n[1], x[2] + n[2], wrap(x[3] + n[3]), R, 1)
        out.append((nav, fix, x.copy()))
    return out


def _nees(ekf: ExtendedKalmanFilter, truth: np.ndarray) -> float:
    est = ekf.latest
    e = est.vector()[:4] - truth[:4]
    e[3] = wrap(e[3])
    P = est.P[:4, :4]
    return float(e @ np.linalg.solve(P, e))


def test_nees_is_within_the_chi_square_bounds() -> None:
    """Average NEES over 20 seeded runs: inside the 95 % two-sided interval of χ²(4·20)/20."""
    runs = 20
    per_step: list[list[float]] = []
    for seed in range(runs):
        ekf = ExtendedKalmanFilter()
        ekf.reset(0.0, 2.0, 3.0, 1.0, 0.3, pos_sigma=0.05, yaw_sigma=0.05)
        vals = []
        for nav, fix, truth in _truth_run(seed):
            ekf.update_navdata(nav)
            if fix is not None:
                ekf.update_marker(fix)
            vals.append(_nees(ekf, truth))
        per_step.append(vals)
    avg = np.mean(np.array(per_step), axis=0)[30:]  # after the start-up transient
    # χ²(80)/20 95 % interval ≈ [2.93, 5.17]; require the time-average inside it and most steps
    lo, hi = 2.93, 5.17
    assert lo < float(np.mean(avg)) < hi
    assert np.mean((avg > lo * 0.7) & (avg < hi * 1.3)) > 0.85


def test_a_late_fix_gives_the_same_state_as_one_in_order() -> None:
    events = _truth_run(3, seconds=3.0, fix_every=1000)
    fix_t, truth = events[20][0].t, events[20][2]
    R = np.diag([0.05**2] * 3 + [0.03**2])
    off = (0.05, -0.05, 0.02, 0.03)
    fix = MarkerFix(fix_t, *(float(truth[i] + off[i]) for i in range(4)), R, 4)
    in_order, late = ExtendedKalmanFilter(), ExtendedKalmanFilter()
    for f in (in_order, late):
        f.reset(0.0, 2.0, 3.0, 1.0, 0.3, pos_sigma=0.3, yaw_sigma=0.3)
    for i, (nav, _, _) in enumerate(events[:30]):
        in_order.update_navdata(nav)
        if i == 20:
            assert in_order.update_marker(fix)
    for nav, _, _ in events[:30]:
        late.update_navdata(nav)
    assert late.update_marker(fix)  # arrives 9 navdata periods late
    assert late.stats.fixes_late == 1
    np.testing.assert_allclose(late.latest.vector(), in_order.latest.vector(), atol=1e-9)
    np.testing.assert_allclose(late.latest.P, in_order.latest.P, atol=1e-12)


def test_a_fix_older_than_the_history_is_dropped() -> None:
    ekf = ExtendedKalmanFilter(EkfConfig(history_s=0.5))
    ekf.reset(0.0, 1, 1, 1, 0)
    for nav, _, _ in _truth_run(1, seconds=2.0, fix_every=1000):
        ekf.update_navdata(nav)
    before = ekf.latest.vector()
    R = np.eye(4) * 1e-4
    assert not ekf.update_marker(MarkerFix(0.2, 1, 1, 1, 0, R))
    assert ekf.stats.fixes_too_old == 1
    np.testing.assert_array_equal(ekf.latest.vector(), before)


def test_an_outlier_is_gated_and_repeated_ones_reinitialise() -> None:
    ekf = ExtendedKalmanFilter(EkfConfig(reinit_after=3))
    ekf.reset(0.0, 1.0, 1.0, 1.0, 0.0, pos_sigma=0.02)
    R = np.diag([0.02**2] * 3 + [0.01**2])
    assert not ekf.update_marker(MarkerFix(0.1, 4.0, 1.0, 1.0, 0.0, R))  # 3 m off: rejected
    assert ekf.latest.x == pytest.approx(1.0, abs=1e-3)
    assert not ekf.update_marker(MarkerFix(0.2, 4.0, 1.0, 1.0, 0.0, R))
    assert ekf.update_marker(MarkerFix(0.3, 4.0, 1.0, 1.0, 0.0, R))  # third: kidnapped, re-init
    assert ekf.latest.x == pytest.approx(4.0)
    assert ekf.stats.reinitialisations == 1


def test_first_fix_initialises_an_unlocalised_filter() -> None:
    ekf = ExtendedKalmanFilter()
    assert not ekf.latest.localised
    R = np.diag([0.03**2] * 3 + [0.02**2])
    assert ekf.update_marker(MarkerFix(0.0, 5.0, 2.0, 1.2, 2.5, R))
    est = ekf.latest
    assert est.localised and est.x == 5.0 and est.yaw_rad == pytest.approx(2.5)
    assert est.P[IX, IX] == pytest.approx(0.03**2)
    assert est.P[IYAW, IYAW] == pytest.approx(0.02**2)


def test_covariance_stays_symmetric_positive_definite() -> None:
    ekf = ExtendedKalmanFilter()
    ekf.reset(0.0, 2.0, 3.0, 1.0, 0.3)
    for nav, fix, _ in _truth_run(7, seconds=30.0, fix_every=1):
        ekf.update_navdata(nav)
        if fix is not None:
            ekf.update_marker(fix)
        P = ekf.latest.P
        assert np.allclose(P, P.T)
    assert np.all(np.linalg.eigvalsh(ekf.latest.P) > 0)


def test_bad_inputs_raise_the_documented_error() -> None:
    ekf = ExtendedKalmanFilter()
    with pytest.raises(EstimatorError):
        ekf.update_navdata(NavdataInput(0.1, float("nan"), 0, 0, 1, 0))
    with pytest.raises(EstimatorError):
        ekf.update_marker(MarkerFix(0.1, 1, 1, 1, 0, np.eye(3)))
    with pytest.raises(EstimatorError):
        ekf.update_marker(MarkerFix(0.1, 1, 1, 1, 0, -np.eye(4)))
    with pytest.raises(EstimatorError):
        ekf.reset(float("inf"), 0, 0, 0, 0)
    # navdata older than the state is not an error, just dropped and counted
    ekf.update_navdata(NavdataInput(1.0, 0, 0, 0, 1, 0))
    assert not ekf.update_navdata(NavdataInput(0.5, 0, 0, 0, 1, 0))
    assert ekf.stats.navdata_rejected == 1
