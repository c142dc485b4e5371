"""The AR.Drone 2.0 front camera's geometry: pinhole model, mounting and map↔camera transforms.

Shared by the real drone's perception (marker pose from the image) and the simulator's renderer,
so neither depends on the other. Frames: map and body frames per docs/CONVENTIONS.md (REP 103);
a pose is ``(x, y, z, roll, pitch, yaw)`` in the map frame, radians; body =
Rz(yaw)·Ry(pitch)·Rx(roll). The camera frame is OpenCV's optical frame: x right, y down,
z forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

PoseLike = Any
"""``(x, y, z, roll, pitch, yaw)`` or an object with ``x, y, z, roll, pitch, yaw_rad``."""

BODY_TO_CAMERA = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
"""Rotation camera←body for the front camera: optical x = −body y, y = −body z, z = body x."""


def pose_tuple(pose: PoseLike) -> tuple[float, float, float, float, float, float]:
    """Normalise a pose to ``(x, y, z, roll, pitch, yaw)``.

    Accepts a 6-sequence, or an object with attributes ``x, y, z, roll, pitch`` and ``yaw_rad``
    (or ``yaw``), e.g. the simulator's truth.

    Raises:
        ValueError: not 6 finite numbers.
    """
    if hasattr(pose, "x"):
        yaw = getattr(pose, "yaw_rad", None)
        if yaw is None:
            yaw = pose.yaw
        vals = (
            pose.x,
            pose.y,
            pose.z,
            getattr(pose, "roll", 0.0),
            getattr(pose, "pitch", 0.0),
            yaw,
        )
    else:
        vals = tuple(pose)
    if len(vals) != 6:
        raise ValueError(f"pose needs 6 values (x, y, z, roll, pitch, yaw), got {len(vals)}")
    out = tuple(float(v) for v in vals)
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"pose values must be finite, got {out}")
    return out  # type: ignore[return-value]


def body_rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Rotation map←body, R = Rz(yaw)·Ry(pitch)·Rx(roll) (REP 103 fixed-axis XYZ)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


@dataclass(frozen=True)
class CameraModel:
    """Pinhole model of the AR.Drone 2.0 front camera (no distortion).

    640×360 with a ≈92° diagonal field of view (AR.Drone Developer Guide SDK 2.0, §1), mounted at
    the body origin looking along body +x.

    ``fx = fy = (diagonal / 2) / tan(diag_fov / 2)``: 354.6 px for 640×360 at 92°; the principal
    point is the image centre in OpenCV's pixel-centre convention ((w−1)/2, (h−1)/2).
    """

    width: int = 640
    height: int = 360
    diag_fov_deg: float = 92.0

    @property
    def fx(self) -> float:
        """Focal length in pixels (square pixels: fy = fx)."""
        half_diag = math.hypot(self.width, self.height) / 2.0
        return half_diag / math.tan(math.radians(self.diag_fov_deg) / 2.0)

    @property
    def fy(self) -> float:
        return self.fx

    @property
    def cx(self) -> float:
        return (self.width - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height - 1) / 2.0

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view."""
        return math.degrees(2.0 * math.atan(self.width / 2.0 / self.fx))

    @property
    def matrix(self) -> np.ndarray:
        """The OpenCV camera matrix K (3×3 float64)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion coefficients (k1, k2, p1, p2, k3): all zero."""
        return np.zeros(5)

    @property
    def body_to_camera(self) -> np.ndarray:
        """Rotation camera←body (``p_cam = R @ p_body``); the camera sits at the body origin."""
        return BODY_TO_CAMERA.copy()

    def scaled(self, factor: float) -> CameraModel:
        """The same optics at another resolution (e.g. 0.5 for the half-size id buffer)."""
        return CameraModel(
            round(self.width * factor), round(self.height * factor), self.diag_fov_deg
        )

    def map_to_camera(self, pose: PoseLike) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) with ``p_cam = R @ p_map + t`` for the drone at ``pose``."""
        x, y, z, roll, pitch, yaw = pose_tuple(pose)
        r = BODY_TO_CAMERA @ body_rotation(roll, pitch, yaw).T
        return r, -r @ np.array([x, y, z])

    def camera_in_map(self, pose: PoseLike) -> tuple[np.ndarray, np.ndarray]:
        """(R_map←cam, camera position in the map) for the drone at ``pose``."""
        x, y, z, roll, pitch, yaw = pose_tuple(pose)
        return body_rotation(roll, pitch, yaw) @ BODY_TO_CAMERA.T, np.array([x, y, z])

    def project(self, points_map: np.ndarray, pose: PoseLike) -> np.ndarray:
        """Project (N, 3) map points to (N, 2) pixels (points behind the camera give NaN)."""
        r, t = self.map_to_camera(pose)
        pc = np.asarray(points_map, float) @ r.T + t
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(z > 1e-9, self.fx * pc[:, 0] / z + self.cx, np.nan)
            v = np.where(z > 1e-9, self.fy * pc[:, 1] / z + self.cy, np.nan)
        return np.stack([u, v], axis=1)
