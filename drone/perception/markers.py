"""ArUco marker localisation: detect DICT_4X4_50 markers, solve each pose, locate the drone.

Pipeline per frame: ``cv2.aruco.ArucoDetector`` → for each known marker
``cv2.solvePnP(..., SOLVEPNP_IPPE_SQUARE)`` with the front camera's intrinsics
(``drone.camera.CameraModel``: 640×360, 92° diagonal, no distortion) → the drone's map-frame
pose from the marker's known pose (``drone.sim.world.Marker``: centre, outward-normal yaw, side)
→ a :class:`~drone.perception.ekf.MarkerFix` with a covariance that grows with distance and
viewing angle.

Geometry (p_cam = R_cm·p_marker + t_cm from PnP; M, m the marker's map rotation and centre;
B = camera←body, camera at the body origin)::

    R_map←body = M·R_cmᵀ·B     yaw = atan2(R[1,0], R[0,0])
    camera (= body) position   c = m − Rz(yaw)·Ry(pitch_nav)·Rx(roll_nav)·Bᵀ·t_cm

(the lever arm uses the navdata attitude: PnP's roll/pitch on a 20-pixel marker are degrees
off, which at 2 m would move the fix by 10 cm).

Noise model (1-σ; fitted to the simulator's renders, see tests/autonomy/test_markers.py), with
d the distance to the marker, θ the angle between its normal and the line of sight, s its side
(s₀ = 0.2 m): yaw σ = (0.4° + 0.6°·d)·(s₀/s)/max(cos θ, 0.3); planar σ = (0.005 + 0.003·d²)·
(s₀/s)/max(cos θ, 0.3); height σ = 0.004 + 0.002·d (it rests on the navdata attitude); plus
the range error 0.006·d²·(s₀/s) along the line of sight (the apparent size of a small marker)
and the yaw error carried through the lever arm, fully correlated with yaw (J·σ²·Jᵀ). Markers
farther than 5 m give no fix.

:class:`PerceptionWorker` runs the detector in its own thread on the newest frame only (a
single-slot mailbox: a slow frame is replaced, never queued); OpenCV releases the GIL.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from drone.camera import body_rotation
from drone.perception.ekf import MarkerFix, wrap
from drone.perception.errors import CameraModelError, FrameError

log = logging.getLogger(__name__)

REF_SIZE_M = 0.2  # s₀ of the noise model
MIN_COS_VIEW = 0.3
MAX_TILT_DISAGREEMENT_RAD = math.radians(15.0)  # PnP attitude vs navdata attitude
AMBIGUITY_RATIO = 3.0  # second IPPE solution within this reprojection-error factor: ambiguous
FLIP_RESOLVABLE_RAD = math.radians(12.0)  # IPPE solutions further apart in yaw: a mirror flip
MAX_FIX_DISTANCE_M = 5.0  # farther markers (< 15 px for 0.2 m) give no fix
MIN_SIDE_PX_NO_PRIOR = 45.0  # without a yaw prior, flips are only resolved on markers this big


@dataclass(frozen=True, eq=False)
class Detection:
    """One detected marker: image corners, its pose in the camera frame, and the drone fix."""

    marker_id: int
    corners: np.ndarray  # (4, 2) pixels, ArUco order TL, TR, BR, BL
    rvec: np.ndarray  # (3,) Rodrigues, marker→camera
    tvec: np.ndarray  # (3,) marker centre in the camera frame, metres
    distance_m: float
    view_angle_rad: float  # 0 = seen head-on
    fix: MarkerFix | None  # None when the id is not in the world map

    def pose_in_camera(self) -> tuple[np.ndarray, np.ndarray]:
        R, _ = cv2.Rodrigues(self.rvec)
        return R, self.tvec


@dataclass(frozen=True)
class FrameResult:
    """Everything perception found in one frame."""

    t: float  # time the frame was captured (its timestamp, not the processing time)
    detections: tuple[Detection, ...]
    rejected_ids: tuple[int, ...]  # detected ids that are not in the world
    process_s: float  # wall time spent detecting + solving


def aruco_detector() -> cv2.aruco.ArucoDetector:
    """The detector of the worlds' markers (4x4, dictionary 50), SUBPIX corners; shared by the
    localiser and the captioner's marker sightings, so both see the same markers."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    # Two adaptive-threshold windows (7 and 23 px) instead of OpenCV's three (3, 13, 23):
    # the markers seen at 0.5-5 m in a 640x360 frame are found by both, at 0.7x the time
    # (bench/autonomy.py; every marker of the room at 1, 1.8 and 2.8 m still detected).
    params.adaptiveThreshWinSizeMin = 7
    params.adaptiveThreshWinSizeMax = 23
    params.adaptiveThreshWinSizeStep = 16
    return cv2.aruco.ArucoDetector(dictionary, params)


class MarkerLocaliser:
    """Detect markers and turn each into a drone pose fix. Not thread-safe; one per worker."""

    RECENT_FRAMES = 4  # the simulator's camera cycles 4 sensor-noise patterns when standing still

    def __init__(self, world: Any, camera: Any) -> None:
        """Args:
        world: a ``drone.sim.world.World`` (or anything with ``markers``).
        camera: a ``drone.camera.CameraModel`` (``matrix``, ``dist_coeffs``,
            ``body_to_camera``).

        Raises:
            CameraModelError: the camera model lacks finite intrinsics.
        """
        try:
            self.K = np.asarray(camera.matrix, dtype=np.float64)
            self.dist = np.asarray(camera.dist_coeffs, dtype=np.float64)
            self.B = np.asarray(camera.body_to_camera, dtype=np.float64)
        except AttributeError as exc:
            raise CameraModelError(f"camera model lacks {exc.name}") from exc
        if self.K.shape != (3, 3) or self.B.shape != (3, 3) or not np.all(np.isfinite(self.K)):
            raise CameraModelError("camera matrix and body_to_camera must be finite 3×3 matrices")
        self.markers = {m.id: m for m in world.markers}
        self.detector = aruco_detector()
        # (grey image, corners, ids) of the last few distinct frames, newest first
        self._recent: list[tuple[np.ndarray, Sequence[np.ndarray], np.ndarray | None]] = []
        self.detections_run = 0  # frames the detector ran on
        self.repeats = 0  # frames answered from ``_recent``

    def process(
        self,
        frame: np.ndarray,
        t: float,
        roll_rad: float = 0.0,
        pitch_rad: float = 0.0,
        yaw_prior: float | None = None,
    ) -> FrameResult:
        """Detect, solve and localise in one frame captured at ``t``.

        ``roll_rad``/``pitch_rad`` (from navdata, REP 103) pick between the two IPPE solutions
        of each square: a far, head-on marker is ambiguous (the pose "flips"), and the flipped
        solution implies a tilt the drone does not have. A vertical marker seen off-axis stays
        ambiguous (the mirror solution differs in yaw by twice the viewing angle, with a similar
        sub-pixel reprojection error): ``yaw_prior`` (the EKF's yaw) breaks the tie; without
        one a fix is only made from a large marker image with a clear reprojection winner.

        Raises:
            FrameError: ``frame`` is not an (H, W, 3) or (H, W) uint8 array.
        """
        if not isinstance(frame, np.ndarray) or frame.dtype != np.uint8 or frame.ndim not in (2, 3):
            raise FrameError("frame must be an (H, W, 3) BGR or (H, W) grey uint8 array")
        if frame.ndim == 3 and frame.shape[2] != 3:
            raise FrameError(f"frame must have 3 channels, got {frame.shape[2]}")
        if min(frame.shape[:2]) < 16:
            raise FrameError(f"frame of shape {frame.shape} is too small")
        start = time.perf_counter()
        attitude = (roll_rad, pitch_rad)
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY) if frame.ndim == 3 else frame.copy()
        corners, ids = self._detect(grey)
        detections: list[Detection] = []
        rejected: list[int] = []
        if ids is not None:
            for c, i in zip(corners, ids.ravel(), strict=True):
                mid = int(i)
                marker = self.markers.get(mid)
                if marker is None:
                    rejected.append(mid)
                    continue
                det = self._solve(
                    marker, np.asarray(c, np.float64).reshape(4, 2), t, attitude, yaw_prior
                )
                if det is not None:
                    detections.append(det)
        return FrameResult(t, tuple(detections), tuple(rejected), time.perf_counter() - start)

    def _detect(self, grey: np.ndarray) -> tuple[Sequence[np.ndarray], np.ndarray | None]:
        """``detectMarkers`` on ``grey``, or its earlier answer when this exact image was among
        the last few (a camera that stands still repeats its frames; the detector's answer
        depends on the pixels alone, so the repeat costs a comparison, not a detection)."""
        probe = grey[::16, ::16]
        for i, (seen, corners, ids) in enumerate(self._recent):
            if np.array_equal(seen[::16, ::16], probe) and np.array_equal(seen, grey):
                self._recent.insert(0, self._recent.pop(i))
                self.repeats += 1
                return corners, ids
        corners, ids, _ = self.detector.detectMarkers(grey)
        self.detections_run += 1
        self._recent.insert(0, (grey, corners, ids))
        del self._recent[self.RECENT_FRAMES :]
        return corners, ids

    def _solve(
        self,
        marker: Any,
        img_pts: np.ndarray,
        t: float,
        attitude: tuple[float, float],
        yaw_prior: float | None,
    ) -> Detection | None:
        size = float(marker.size_m)
        h = size / 2.0
        obj = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(
            obj, img_pts, self.K, self.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
        if not n:
            return None
        M = marker.rotation()
        m = np.asarray(marker.position, np.float64)
        # (reprojection error, |yaw − prior|, rvec, tvec, R_cm, pose) of the plausible solutions
        cands: list[tuple[float, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for rv, tv, err in zip(rvecs, tvecs, np.ravel(errs), strict=False):
            if not (
                math.isfinite(float(err)) and np.all(np.isfinite(rv)) and np.all(np.isfinite(tv))
            ):
                continue  # IPPE_SQUARE gives a NaN solution for some corner sets (OpenCV 4.9-5.0)
            R_cm, _ = cv2.Rodrigues(rv)
            R_map_cam = M @ R_cm.T
            R_mb = R_map_cam @ self.B
            pitch = -math.asin(max(-1.0, min(1.0, R_mb[2, 0])))
            roll = math.atan2(R_mb[2, 1], R_mb[2, 2])
            if math.hypot(roll - attitude[0], pitch - attitude[1]) > MAX_TILT_DISAGREEMENT_RAD:
                continue  # implies a tilt the drone does not have
            yaw = math.atan2(R_mb[1, 0], R_mb[0, 0])
            # The lever arm from the marker to the camera uses the navdata roll/pitch (good to
            # ~0.1°) rather than PnP's (degrees off on a small marker): c = m − R·Bᵀ·t.
            R_att = body_rotation(attitude[0], attitude[1], yaw) @ self.B.T
            c = m - R_att @ tv.ravel()
            # ∂c/∂yaw: a yaw error swings the position around the marker (lever arm d)
            lever = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]) @ (c - m)
            pose = np.array([c[0], c[1], c[2], yaw, *lever, *(c - m)])
            dyaw = abs(wrap(yaw - yaw_prior)) if yaw_prior is not None else 0.0
            cands.append((float(err), dyaw, rv.ravel(), tv.ravel(), R_cm, pose))
        if not cands:
            return None
        cands.sort(key=lambda c: c[0])
        inflate = np.zeros(4)
        if len(cands) > 1:
            diff = (cands[1][5] - cands[0][5])[:4]
            diff[3] = wrap(diff[3])
            if abs(diff[3]) > FLIP_RESOLVABLE_RAD:
                # A mirror flip. Sub-pixel reprojection errors cannot be trusted to tell the two
                # apart on a small marker, so the yaw prior decides; without one, only a large
                # marker image with a clear reprojection winner gives a fix.
                if yaw_prior is not None:
                    cands.sort(key=lambda c: c[1])
                else:
                    side_px = float(np.ptp(img_pts[:, 0]))
                    clear = cands[1][0] >= AMBIGUITY_RATIO * max(cands[0][0], 1e-3)
                    if side_px < MIN_SIDE_PX_NO_PRIOR or not clear:
                        return None
            elif cands[1][0] < AMBIGUITY_RATIO * max(cands[0][0], 1e-3):
                # Near head-on the two solutions are close: keep the better-fitting one and
                # widen the covariance to cover the other (the ambiguity is measurement noise).
                inflate = (diff / 2.0) ** 2
        _, _, rvec, tvec, R_cm, pose = cands[0]
        d = float(np.linalg.norm(tvec))
        if not math.isfinite(d) or d <= 1e-6:
            return None
        cos_view = float(-R_cm[:, 2] @ tvec / d)  # marker normal vs. direction to the camera
        if d > MAX_FIX_DISTANCE_M:
            return None
        R = fix_covariance(d, cos_view, size, lever=pose[4:7], sight=pose[7:10]) + np.diag(inflate)
        fix = MarkerFix(
            t, float(pose[0]), float(pose[1]), float(pose[2]), float(pose[3]), R, int(marker.id)
        )
        view = math.acos(max(-1.0, min(1.0, cos_view)))
        return Detection(int(marker.id), img_pts, rvec, tvec, d, view, fix)


def fix_covariance(
    distance_m: float,
    cos_view: float,
    size_m: float = REF_SIZE_M,
    lever: np.ndarray | None = None,
    sight: np.ndarray | None = None,
) -> np.ndarray:
    """4×4 covariance of (x, y, z, yaw) of a fix (module docstring's noise model).

    ``lever`` = ∂position/∂yaw (metres per radian): the yaw error's share of the position error
    is correlated with it (J·σ²·Jᵀ), as a first-order propagation of the yaw noise. ``sight``:
    the marker→camera vector; the range error (the marker's apparent size) lies along it.
    """
    k = 1.0 / max(cos_view, MIN_COS_VIEW)
    scale = REF_SIZE_M / size_m
    sp = (0.005 + 0.003 * distance_m**2) * scale * k
    sz = 0.004 + 0.002 * distance_m
    sy = math.radians(0.4 + 0.6 * distance_m) * scale * k
    sr = 0.006 * distance_m**2 * scale  # range: σ_px·d²/(f·s) with σ_px ≈ 0.4 px, f = 355 px
    R = np.diag([sp * sp, sp * sp, sz * sz, sy * sy])
    if sight is not None:
        n = float(np.linalg.norm(sight))
        if n > 1e-9:
            u = np.append(np.asarray(sight) / n, 0.0)
            R = R + np.outer(u, u) * (sr * sr)
    if lever is not None:
        J = np.array([lever[0], lever[1], lever[2], 1.0])  # ∂(x, y, z, yaw)/∂yaw
        R = R + np.outer(J, J) * (sy * sy) - np.diag([0.0, 0.0, 0.0, sy * sy])
    return R


def draw_overlay(
    frame: np.ndarray,
    result: FrameResult | None,
    camera: Any,
    lines: Sequence[str] = (),
) -> np.ndarray:
    """A copy of ``frame`` with marker outlines, ids, axes, distances and status ``lines``."""
    img = frame.copy() if frame.ndim == 3 else cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if result is not None:
        K = np.asarray(camera.matrix, np.float64)
        dist = np.asarray(camera.dist_coeffs, np.float64)
        for det in result.detections:
            pts = det.corners.reshape(-1, 1, 2).astype(np.int32)
            cv2.polylines(img, [pts], True, (0, 255, 0), 2, cv2.LINE_AA)
            cv2.drawFrameAxes(img, K, dist, det.rvec, det.tvec, 0.1, 2)
            x, y = det.corners[0]
            label = f"#{det.marker_id} {det.distance_m:.2f} m"
            cv2.putText(
                img,
                label,
                (int(x), max(12, int(y) - 6)),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.45,
                (0, 255, 0),
                1,
                cv2.LINE_AA,
            )
    for k, text in enumerate(lines):
        org = (8, 18 + 16 * k)
        # A dark box rather than a thick outline: OpenCV spaces glyphs by thickness, so a
        # thick outline under thin text does not line up.
        (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1)
        top_left = (org[0] - 3, org[1] - h - 3)
        bottom_right = (org[0] + w + 3, org[1] + base)
        cv2.rectangle(img, top_left, bottom_right, (0, 0, 0), -1)
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return img


class PerceptionWorker:
    """Runs a :class:`MarkerLocaliser` in its own thread on the newest submitted frame.

    ``on_result(result)`` is called from the worker thread for every processed frame (the vehicle
    feeds the fixes to its EKF there). ``context()`` gives (roll, pitch, yaw prior or None) at
    processing time (navdata attitude and the EKF's yaw). ``dropped`` counts frames replaced
    before processing.
    """

    def __init__(
        self,
        localiser: MarkerLocaliser,
        on_result: Callable[[FrameResult], None],
        context: Callable[[], tuple[float, float, float | None]] | None = None,
    ) -> None:
        self._loc = localiser
        self._on_result = on_result
        self._context = context
        self._cond = threading.Condition()
        self._slot: tuple[np.ndarray, float] | None = None
        self._stop = False
        self._thread: threading.Thread | None = None
        self.processed = 0
        self.dropped = 0
        self.errors = 0
        self.last_result: FrameResult | None = None

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="perception", daemon=True)
            self._thread.start()

    def stop(self, timeout: float = 1.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)

    def submit(self, frame: np.ndarray, t: float) -> None:
        """Hand over a frame (replaces one not yet processed)."""
        with self._cond:
            if self._slot is not None:
                self.dropped += 1
            self._slot = (frame, t)
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._slot is None and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                assert self._slot is not None
                frame, t = self._slot
                self._slot = None
            try:
                roll, pitch, prior = self._context() if self._context else (0.0, 0.0, None)
                result = self._loc.process(frame, t, roll, pitch, prior)
            except FrameError as exc:
                self.errors += 1
                log.warning("perception skipped a frame: %s", exc)
                continue
            self.processed += 1
            self.last_result = result
            try:
                self._on_result(result)
            except Exception:
                self.errors += 1
                log.exception("perception result handler failed")
