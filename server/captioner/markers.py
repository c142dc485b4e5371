"""ArUco markers in the frame being described: the authority on marker ids and where they are.

The same detector settings as the drone's localiser (``drone/perception/markers.py``:
DICT_4X4_50, sub-pixel corners, adaptive-threshold windows 7 and 23 px), run on the very frame
that is described, so a description never names a marker the image does not show.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from drone.camera import CameraModel
from drone.perception.markers import aruco_detector
from server.captioner.grounding import SeenMarker

_CAMERA = CameraModel()  # AR.Drone 2.0 front camera: 640×360, 92° diagonal


@dataclass(frozen=True)
class MarkerSighting:
    """A detected marker: its id, bearing (degrees, left positive) and image bounding box."""

    id: int
    bearing_deg: float
    box: tuple[int, int, int, int]  # x0, y0, x1, y1 (pixels, inclusive)

    def seen(self) -> SeenMarker:
        return SeenMarker(self.id, self.bearing_deg)


class MarkerDetector:
    """``cv2.aruco`` with the localiser's parameters; not thread-safe (one per worker)."""

    def __init__(self) -> None:
        self._detector = aruco_detector()

    def detect(self, frame_bgr: npt.NDArray[np.uint8]) -> list[MarkerSighting]:
        """Markers in a BGR frame, left to right; bearings use the front camera's optics
        scaled to the frame's width."""
        grey = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = self._detector.detectMarkers(grey)
        if ids is None:
            return []
        h, w = grey.shape
        cam = _CAMERA.scaled(w / _CAMERA.width)
        out: list[MarkerSighting] = []
        seen: set[int] = set()
        for c, i in zip(corners, ids.ravel(), strict=True):
            mid = int(i)
            if mid in seen:
                continue
            seen.add(mid)
            pts = np.asarray(c, np.float64).reshape(4, 2)
            u = float(pts[:, 0].mean())
            bearing = math.degrees(math.atan2(cam.cx - u, cam.fx))
            x0, y0 = np.floor(pts.min(axis=0)).astype(int)
            x1, y1 = np.ceil(pts.max(axis=0)).astype(int)
            box = (max(int(x0), 0), max(int(y0), 0), min(int(x1), w - 1), min(int(y1), h - 1))
            out.append(MarkerSighting(mid, bearing, box))
        out.sort(key=lambda m: -m.bearing_deg)
        return out
