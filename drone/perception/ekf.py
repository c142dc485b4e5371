"""Extended Kalman filter of the drone's map-frame pose, fusing navdata and marker fixes.

State (filterpy notation; every symbol commented where it is used)::

    x = [px, py, pz, ψ, vx, vy, vz]ᵀ     map frame (REP 103): metres, radians (CCW), m/s

Predict (at the navdata rate, ~15 Hz demo / 200 Hz full): constant velocity, yaw integrated
from the yaw rate the navdata gives (difference of successive psi); process noise is the
discrete white-noise-acceleration model (Bar-Shalom, *Estimation with Applications to
Tracking*, §6.3.3). Its vertical acceleration level is the drone's own, not a smoothing knob:
the onboard controller reaches ``control_vz_max`` (0.7 m/s indoor, 1 m/s outdoor) with a lag
of ~0.25 s, so a climb-to-descent reversal accelerates at up to ~5 m/s²; σa,z = 3 m/s² covers
it (with a σ of 0.5 m/s² every navdata packet of such a reversal would be an "outlier").
Navdata update: z = [v_forward, v_left, v_up, altitude] with h(x) = [R(ψ)ᵀ v_xy, vz, pz]
(ardrone_autonomy's body-frame velocities; altitude from ultrasound over a flat floor), fused
component by component — planar velocity (2 dof), vertical speed (1), altitude (1) — each with
its own gate, so one implausible component never drops the others (the ultrasound, the most
trusted height source, is never locked out by a velocity jump). A component rejected
``nav_reinit_after`` times in a row re-initialises that part of the state from navdata
(counted in ``EkfStats.navdata_reinits``), and while a component keeps being rejected the
estimate says so (:attr:`Estimate.disagreement`) for the ANS to tell the operator. A drone
standing landed (``NavdataInput.landed``) gets no process noise: it cannot wander, so its pose
stays as certain as when it touched down. A drone whose motors are cut (``NavdataInput.unpowered``:
the EMERGENCY state) falls at g and stops dead on the floor, which the constant-velocity model with
σa,z = 3 m/s² cannot follow: its navdata is fused without the gate (the sensors are all there is
to know about a falling drone), so the fall is neither rejected, re-initialised nor reported as a
disagreement (the ANS said "estimate disagrees" after every emergency stop before).
Marker update: z = [px, py, pz, ψ] from one marker's PnP pose,
H linear, R from ``markers.py`` (grows with distance and viewing angle).

Numerics: Joseph-form covariance update P = (I−KH)P(I−KH)ᵀ + KRKᵀ (stays symmetric positive
definite in floating point; filterpy ``KalmanFilter.update`` does the same). Yaw innovations are
wrapped to [−π, π). Outliers: Mahalanobis gating, d² = yᵀS⁻¹y > χ²(dof, 0.999) is rejected;
after ``reinit_after`` consecutive rejected marker fixes the filter re-initialises from the fix
(a kidnapped drone must not be locked out by its own over-confidence).

Late measurements: camera frames arrive after the navdata of the same instant (decode,
detection). The filter keeps ~``history_s`` of (time, x, P, input) after each navdata event; a
fix stamped in the past restores the snapshot just before it, applies the fix at its own time,
and re-propagates the later navdata events (re-propagation, Bar-Shalom & Li out-of-sequence
"algorithm A"-style, exact for a linear H). Fixes older than the history are counted and dropped.

Thread safety: one lock around every mutation; readers take :attr:`ExtendedKalmanFilter.latest`,
an immutable :class:`Estimate` whose reference is swapped atomically (the 100 Hz controller never
waits on the lock).
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from drone.perception.errors import EstimatorError

NX = 7  # state size
IX, IY, IZ, IYAW, IVX, IVY, IVZ = range(NX)
CHI2_999 = {1: 10.83, 2: 13.82, 3: 16.27, 4: 18.47}  # χ² 99.9 % quantiles by dof
NAV_COMPONENTS = ("velocity", "vertical speed", "altitude")  # navdata parts, gated one by one


def wrap(a: float) -> float:
    """Wrap an angle to [−π, π)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class NavdataInput:
    """One navdata event in REP 103 terms (``BodyState`` of drone/ardrone/navdata.py)."""

    t: float  # seconds, the vehicle's clock
    vx_body: float  # forward m/s
    vy_body: float  # left m/s
    vz: float  # up m/s
    altitude_m: float  # ultrasound height over the floor
    yaw_rate: float  # CCW rad/s (from successive psi)
    landed: bool = False  # on the floor with the motors off: the drone cannot move
    unpowered: bool = False  # motors cut (EMERGENCY): falling, or lying where it fell


@dataclass(frozen=True, eq=False)
class MarkerFix:
    """A drone pose measured from one marker: map-frame position, yaw, and its 4×4 covariance."""

    t: float
    x: float
    y: float
    z: float
    yaw_rad: float
    R: np.ndarray  # 4×4 measurement covariance (m², rad²)
    marker_id: int = -1


@dataclass(frozen=True, eq=False)
class Estimate:
    """An immutable snapshot of the filter (what the controller and telemetry read)."""

    t: float
    x: float
    y: float
    z: float
    yaw_rad: float
    vx: float
    vy: float
    vz: float
    P: np.ndarray = field(repr=False)  # 7×7 covariance (a private copy)
    localised: bool = False  # at least one marker fix has been accepted
    last_fix_t: float | None = None
    # navdata components (NAV_COMPONENTS) the filter has rejected ``disagree_after`` times in a
    # row: the estimate and the drone's own sensors disagree (ANS alert)
    disagreement: tuple[str, ...] = ()

    @property
    def position_sigma_m(self) -> float:
        """Planar 1-σ radius: sqrt(σx² + σy²)."""
        return float(math.sqrt(max(self.P[IX, IX] + self.P[IY, IY], 0.0)))

    @property
    def yaw_sigma_rad(self) -> float:
        return float(math.sqrt(max(self.P[IYAW, IYAW], 0.0)))

    def vector(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z, self.yaw_rad, self.vx, self.vy, self.vz])


@dataclass(frozen=True)
class EkfConfig:
    """Noise levels (1-σ) and bookkeeping; defaults suit the AR.Drone 2.0 and its simulator."""

    accel_sigma_xy: float = 1.0  # m/s², white acceleration (process noise)
    accel_sigma_z: float = 3.0  # m/s²: control_vz_max / vz lag ≈ 0.7 / 0.25 (module docstring)
    yaw_rate_sigma: float = 0.05  # rad/s, error of the navdata yaw rate
    vel_sigma: float = 0.08  # m/s, navdata optical-flow velocity noise
    vz_sigma: float = 0.08  # m/s
    alt_sigma: float = 0.03  # m, ultrasound
    history_s: float = 1.0  # how far back a late fix may reach
    reinit_after: int = 8  # consecutive rejected fixes before re-initialising from a fix
    nav_reinit_after: int = 8  # consecutive rejections of a navdata component (~0.5 s at 15 Hz)
    disagree_after: int = 3  # consecutive rejections before the estimate reports disagreement
    init_pos_sigma: float = 3.0  # m, before any fix
    init_yaw_sigma: float = math.pi  # rad, before any fix


@dataclass
class EkfStats:
    navdata_updates: int = 0
    navdata_rejected: int = 0
    fixes_accepted: int = 0
    fixes_rejected: int = 0
    fixes_too_old: int = 0
    fixes_late: int = 0
    reinitialisations: int = 0
    navdata_reinits: int = 0  # a navdata component re-initialised after persistent rejection
    navdata_component_rejects: dict[str, int] = field(default_factory=dict)  # by component
    last_nis: float = 0.0  # normalised innovation squared of the last marker fix


@dataclass
class _Entry:
    t: float
    x: np.ndarray
    P: np.ndarray
    omega: float  # yaw rate in force after this event
    nav: NavdataInput | None  # the navdata event that produced this entry
    fix: tuple[MarkerFix, np.ndarray] | None = None  # or the marker fix (and its R)
    nav_rejects: dict[str, int] = field(default_factory=dict)  # rejections in a row, then


def _finite(*vals: float) -> bool:
    return all(math.isfinite(v) for v in vals)


class ExtendedKalmanFilter:
    """The estimator of one vehicle; see the module docstring."""

    def __init__(self, config: EkfConfig | None = None, t0: float = 0.0) -> None:
        self.cfg = config or EkfConfig()
        self.x = np.zeros(NX)  # state mean
        self.P = np.diag(  # state covariance
            [self.cfg.init_pos_sigma**2] * 2 + [0.25, self.cfg.init_yaw_sigma**2] + [0.25] * 3
        )
        self.t = t0  # time of the state
        self.omega = 0.0  # last yaw-rate input, rad/s
        self.localised = False
        self.last_fix_t: float | None = None
        self.stats = EkfStats()
        self._rejects_in_row = 0
        self._nav_rejects_in_row = dict.fromkeys(NAV_COMPONENTS, 0)
        self._history: deque[_Entry] = deque()
        self._lock = threading.Lock()
        self.latest = self._snapshot()

    # -- public -------------------------------------------------------------------------------
    def reset(
        self,
        t: float,
        x: float,
        y: float,
        z: float,
        yaw_rad: float,
        pos_sigma: float = 0.05,
        yaw_sigma: float = math.radians(2.0),
        localised: bool = True,
    ) -> None:
        """Start from a known pose (e.g. the drone stands on its home station)."""
        if not _finite(t, x, y, z, yaw_rad, pos_sigma, yaw_sigma):
            raise EstimatorError("reset values must be finite")
        with self._lock:
            self.t = t
            self.x = np.array([x, y, z, wrap(yaw_rad), 0.0, 0.0, 0.0])
            self.P = np.diag([pos_sigma**2] * 3 + [yaw_sigma**2] + [0.01] * 3)
            self.localised = localised
            self._history.clear()
            self._publish()

    def update_navdata(self, nav: NavdataInput) -> bool:
        """Predict to ``nav.t`` with its yaw rate, then update with its velocities and altitude.

        Returns False (and counts it) when the event is older than the state or gated out.

        Raises:
            EstimatorError: a value is NaN/Inf.
        """
        if not _finite(nav.t, nav.vx_body, nav.vy_body, nav.vz, nav.altitude_m, nav.yaw_rate):
            raise EstimatorError(f"navdata input not finite: {nav}")
        with self._lock:
            if nav.t < self.t:
                self.stats.navdata_rejected += 1
                return False
            ok = self._apply_navdata(nav)
            self._remember(nav)
            self._publish()
            return ok

    def update_marker(self, fix: MarkerFix) -> bool:
        """Fuse a marker fix at its own timestamp (re-propagating later navdata if it is late).

        Returns True if accepted, False if gated out or older than the history.

        Raises:
            EstimatorError: a value is NaN/Inf or R is not a symmetric positive 4×4 matrix.
        """
        R = np.asarray(fix.R, dtype=float)
        if not _finite(fix.t, fix.x, fix.y, fix.z, fix.yaw_rad) or R.shape != (4, 4):
            raise EstimatorError(f"marker fix must be finite with a 4×4 covariance: {fix}")
        if not np.all(np.isfinite(R)) or np.any(np.linalg.eigvalsh((R + R.T) / 2) <= 0):
            raise EstimatorError("marker fix covariance must be symmetric positive definite")
        with self._lock:
            ok = self._fuse_fix(fix, R)
            self._publish()
            return ok

    def predict_to(self, t: float) -> None:
        """Propagate the state to ``t`` without a measurement (e.g. for a telemetry stamp)."""
        with self._lock:
            if t > self.t:
                self._predict(t - self.t, self.omega)
                self.t = t
                self._publish()

    # -- filter equations ---------------------------------------------------------------------
    def _predict(self, dt: float, omega: float, still: bool = False) -> None:
        """Propagate by ``dt``; ``still``: the drone stands landed (no process noise at all —
        a drone on the floor does not wander, so its pose stays as certain as when it landed,
        and a later take-off needs no tag search to find itself again)."""
        c = self.cfg
        if still:  # on the floor the velocity is known: zero, exactly (no noise to integrate)
            vel = [IVX, IVY, IVZ]
            self.x[vel] = 0.0
            self.P[vel, :] = 0.0
            self.P[:, vel] = 0.0
        # F: state transition Jacobian (constant velocity; yaw driven by the input ω)
        F = np.eye(NX)
        F[IX, IVX] = F[IY, IVY] = F[IZ, IVZ] = dt
        self.x = F @ self.x
        self.x[IYAW] = wrap(self.x[IYAW] + omega * dt)
        # Q: process noise; white acceleration per axis [[dt⁴/4, dt³/2], [dt³/2, dt²]]·σa²
        Q = np.zeros((NX, NX))
        for ip, iv, sa in (
            (IX, IVX, c.accel_sigma_xy),
            (IY, IVY, c.accel_sigma_xy),
            (IZ, IVZ, c.accel_sigma_z),
        ):
            q = sa * sa
            Q[ip, ip] = q * dt**4 / 4
            Q[ip, iv] = Q[iv, ip] = q * dt**3 / 2
            Q[iv, iv] = q * dt**2
        Q[IYAW, IYAW] = (c.yaw_rate_sigma * dt) ** 2 + 1e-8 * dt  # ω error, plus a tiny floor
        if still:
            Q[:] = 0.0
        self.P = F @ self.P @ F.T + Q

    def _update(
        self, y: np.ndarray, H: np.ndarray, R: np.ndarray, gate: bool
    ) -> tuple[bool, float]:
        """Gated Joseph-form update with innovation ``y`` (z − h(x)); returns (accepted, d²)."""
        S = H @ self.P @ H.T + R  # innovation covariance
        Si = np.linalg.inv(S)
        d2 = float(y @ Si @ y)  # squared Mahalanobis distance (NIS)
        if gate and d2 > CHI2_999[len(y)]:
            return False, d2
        K = self.P @ H.T @ Si  # Kalman gain
        self.x = self.x + K @ y
        self.x[IYAW] = wrap(self.x[IYAW])
        I_KH = np.eye(NX) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + K @ R @ K.T  # Joseph form
        self.P = (self.P + self.P.T) / 2
        return True, d2

    def _apply_navdata(self, nav: NavdataInput) -> bool:
        """Predict to ``nav.t``, then fuse each navdata component under its own gate.

        Returns False when any component was rejected (and not re-initialised). With the
        motors cut (``nav.unpowered``) nothing is gated: the model does not hold (module doc).
        """
        c = self.cfg
        gate = not nav.unpowered
        self._predict(nav.t - self.t, nav.yaw_rate, still=nav.landed)
        self.t = nav.t
        self.omega = nav.yaw_rate
        ok = True
        # altitude first: the most trusted height source (ultrasound, σ ~ 3 cm)
        ok &= self._nav_component("altitude", IZ, nav.altitude_m, c.alt_sigma**2, nav, gate)
        ok &= self._nav_component("vertical speed", IVZ, nav.vz, c.vz_sigma**2, nav, gate)
        psi, vx, vy = self.x[IYAW], self.x[IVX], self.x[IVY]
        cs, sn = math.cos(psi), math.sin(psi)
        # h(x): body-frame velocities Rᵀ(ψ)·v, and its Jacobian ∂h/∂x
        hx = np.array([cs * vx + sn * vy, -sn * vx + cs * vy])
        H = np.zeros((2, NX))
        H[0, IYAW], H[0, IVX], H[0, IVY] = -sn * vx + cs * vy, cs, sn
        H[1, IYAW], H[1, IVX], H[1, IVY] = -cs * vx - sn * vy, -sn, cs
        y = np.array([nav.vx_body, nav.vy_body]) - hx
        R = np.eye(2) * c.vel_sigma**2
        ok &= self._nav_component("velocity", (y, H, R), 0.0, 0.0, nav, gate)
        if ok:
            self.stats.navdata_updates += 1
        else:
            self.stats.navdata_rejected += 1
        return bool(ok)

    def _update_direct(self, i: int, z: float, r: float, gate: bool = True) -> bool:
        """Gated (unless ``gate`` is False) update of a measurement of state ``i`` itself
        (H = eᵢ, scalar R = ``r``).

        The general update specialised: S = Pᵢᵢ + r, K = P·eᵢ / S, and the Joseph form
        (I−KH)P(I−KH)ᵀ + K r Kᵀ reduces exactly to P − S·K·Kᵀ (symmetric by construction);
        no matrix inverse, a third of the cost of the general path.
        """
        y = z - self.x[i]
        S = self.P[i, i] + r
        if gate and y * y / S > CHI2_999[1]:
            return False
        K = self.P[:, i] / S
        self.x = self.x + K * y
        self.x[IYAW] = wrap(self.x[IYAW])
        self.P = self.P - S * np.outer(K, K)
        self.P = (self.P + self.P.T) / 2
        return True

    def _nav_component(
        self,
        name: str,
        which: int | tuple[np.ndarray, np.ndarray, np.ndarray],
        z: float,
        r: float,
        nav: NavdataInput,
        gate: bool = True,
    ) -> bool:
        """Gated update of one navdata component; re-initialise it after persistent rejection.

        A single implausible value (the ultrasound jumping onto a table, a glitch of the optical
        flow) is gated out; ``nav_reinit_after`` in a row means the *estimate* is what is wrong
        (navdata is the drone's own sensing), so that part of the state restarts from navdata.
        """
        if isinstance(which, int):  # a state measured directly (altitude, vertical speed)
            ok = self._update_direct(which, z, r, gate)
        else:  # (innovation, Jacobian, R)
            ok, _ = self._update(*which, gate=gate)
        if ok:
            self._nav_rejects_in_row[name] = 0
            return True
        rejects = self.stats.navdata_component_rejects
        rejects[name] = rejects.get(name, 0) + 1
        self._nav_rejects_in_row[name] += 1
        if self._nav_rejects_in_row[name] < self.cfg.nav_reinit_after:
            return False
        self._reinit_from_navdata(name, nav)
        self._nav_rejects_in_row[name] = 0
        self.stats.navdata_reinits += 1
        return True

    def _reinit_from_navdata(self, name: str, nav: NavdataInput) -> None:
        c = self.cfg
        if name == "altitude":  # height and vertical speed go together
            idx, values, var = [IZ, IVZ], [nav.altitude_m, nav.vz], [c.alt_sigma, c.vz_sigma]
        elif name == "vertical speed":
            idx, values, var = [IVZ], [nav.vz], [c.vz_sigma]
        else:
            psi = self.x[IYAW]
            cs, sn = math.cos(psi), math.sin(psi)
            idx = [IVX, IVY]
            values = [cs * nav.vx_body - sn * nav.vy_body, sn * nav.vx_body + cs * nav.vy_body]
            var = [c.vel_sigma, c.vel_sigma]
        self.x[idx] = values
        self.P[idx, :] = 0.0
        self.P[:, idx] = 0.0
        self.P[idx, idx] = np.square(var)

    def _apply_fix(self, fix: MarkerFix, R: np.ndarray) -> bool:
        if fix.t > self.t:
            self._predict(fix.t - self.t, self.omega)
            self.t = fix.t
        H = np.zeros((4, NX))  # the fix observes position and yaw directly
        H[0, IX] = H[1, IY] = H[2, IZ] = H[3, IYAW] = 1.0
        y = np.array([fix.x, fix.y, fix.z, fix.yaw_rad]) - H @ self.x
        y[3] = wrap(y[3])
        if not self.localised:
            self._init_from_fix(fix, R)
            return True
        ok, d2 = self._update(y, H, R, gate=True)
        self.stats.last_nis = d2
        if ok:
            self._rejects_in_row = 0
            return True
        self._rejects_in_row += 1
        if self._rejects_in_row >= self.cfg.reinit_after:
            self._init_from_fix(fix, R)
            self.stats.reinitialisations += 1
            return True
        return False

    def _init_from_fix(self, fix: MarkerFix, R: np.ndarray) -> None:
        self.x[[IX, IY, IZ, IYAW]] = [fix.x, fix.y, fix.z, wrap(fix.yaw_rad)]
        idx = [IX, IY, IZ, IYAW]
        self.P[idx, :] = 0.0
        self.P[:, idx] = 0.0
        self.P[np.ix_(idx, idx)] = R
        self.localised = True
        self._rejects_in_row = 0

    def _fuse_fix(self, fix: MarkerFix, R: np.ndarray) -> bool:
        if fix.t >= self.t or not self._history:
            ok = self._apply_fix(fix, R)
            self._after_fix(fix, ok)
            return ok
        # Late fix: find the last snapshot at or before fix.t, re-run from there.
        times = [e.t for e in self._history]
        i = bisect.bisect_right(times, fix.t) - 1
        if i < 0:
            self.stats.fixes_too_old += 1
            return False
        self.stats.fixes_late += 1
        base = self._history[i]
        later = list(self._history)[i + 1 :]
        self.x, self.P, self.t, self.omega = base.x.copy(), base.P.copy(), base.t, base.omega
        self._nav_rejects_in_row = dict(base.nav_rejects)
        while len(self._history) > i + 1:
            self._history.pop()
        # Over [t_n, fix.t] the yaw turned at the rate the *next* navdata reports (its rate is
        # the mean over [t_n, t_n+1]), not the rate of the interval before.
        nxt = next((e.nav for e in later if e.nav is not None), None)
        if nxt is not None:
            self.omega = nxt.yaw_rate
        ok = self._apply_fix(fix, R)
        self._after_fix(fix, ok)
        for e in later:  # re-propagate everything that came after, in time order
            if e.nav is not None:
                self._apply_navdata(e.nav)
                self._remember(e.nav)
            elif e.fix is not None:
                self._after_fix(e.fix[0], self._apply_fix(*e.fix), count=False)
        return ok

    def _after_fix(self, fix: MarkerFix, ok: bool, count: bool = True) -> None:
        if ok:
            self.stats.fixes_accepted += count
            self.last_fix_t = fix.t if self.last_fix_t is None else max(self.last_fix_t, fix.t)
        else:
            self.stats.fixes_rejected += count
        self._remember(None, (fix, np.asarray(fix.R, dtype=float)))

    def _remember(
        self, nav: NavdataInput | None, fix: tuple[MarkerFix, np.ndarray] | None = None
    ) -> None:
        self._history.append(
            _Entry(
                self.t,
                self.x.copy(),
                self.P.copy(),
                self.omega,
                nav,
                fix,
                dict(self._nav_rejects_in_row),
            )
        )
        while self._history and self._history[0].t < self.t - self.cfg.history_s:
            self._history.popleft()

    def _snapshot(self) -> Estimate:
        x = self.x
        return Estimate(
            t=self.t,
            x=float(x[IX]),
            y=float(x[IY]),
            z=float(x[IZ]),
            yaw_rad=float(x[IYAW]),
            vx=float(x[IVX]),
            vy=float(x[IVY]),
            vz=float(x[IVZ]),
            P=self.P.copy(),
            localised=self.localised,
            last_fix_t=self.last_fix_t,
            disagreement=tuple(
                n for n in NAV_COMPONENTS if self._nav_rejects_in_row[n] >= self.cfg.disagree_after
            ),
        )

    def _publish(self) -> None:
        self.latest = self._snapshot()  # atomic reference swap
