"""The simulated AR.Drone 2.0 front camera: camera model, a fast perspective renderer and the
scene graph of what the camera sees.

- the camera's geometry (:class:`~drone.camera.CameraModel`, 640×360, ≈92° diagonal FOV) lives
  in ``drone/camera.py``, shared with the real drone's perception.
- :class:`Renderer`: ``render(pose) -> (360, 640, 3) uint8 BGR`` in ≈2–4 ms: a painter's algorithm
  over convex polygons (``cv2.fillConvexPoly`` with sub-pixel vertices), polygons clipped against
  the near plane and a guard-band frustum, real ``cv2.aruco`` DICT_4X4_50 bitmaps warped by their
  exact homography into a region of interest so ``cv2.aruco`` + ``solvePnP`` recover their pose.
- :func:`visible_objects`: occlusion-aware list of visible objects and markers (an id-buffer render
  at half resolution) with bearing, distance, side and bounding box — the captioner's scene graph.

Frames: map and body frames per docs/CONVENTIONS.md (REP 103). A pose is
``(x, y, z, roll, pitch, yaw)`` in the map frame, radians; body = Rz(yaw)·Ry(pitch)·Rx(roll).
Camera frame is OpenCV's optical frame: x right, y down, z forward.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import cv2
import numpy as np

from drone.camera import CameraModel, PoseLike, pose_tuple
from drone.sim.world import Marker, SceneObject, World

# ---------------------------------------------------------------------------------------------
# scene construction: every object is a few cuboids, every cuboid six quads

# Cuboid parts in object-local fractions: (x centre, y centre, z bottom, dx, dy, dz, colour, layer)
# x along the object's depth (front = +x), y along its width, z up from its base (fractions of
# size d, w, h). colour None = the object's colour; a BGR tuple otherwise; "dark" = 0.45×colour.
_Part = tuple[float, float, float, float, float, float, Any, int]
_SKIN = (140, 170, 215)
_JEANS = (90, 60, 40)
_WOOD = (45, 80, 125)
_GLASS_DARK = (90, 70, 50)
_SHAPES: dict[str, list[_Part]] = {
    "box": [(0, 0, 0, 1, 1, 1, None, 0)],
    "post": [(0, 0, 0, 1, 1, 1, None, 0)],
    "chair": [
        (0, 0, 0.45, 1, 1, 0.07, None, 0),
        (-0.44, 0, 0.52, 0.12, 1, 0.48, None, 0),
        *[(sx * 0.42, sy * 0.42, 0, 0.1, 0.1, 0.45, "dark", 0) for sx in (-1, 1) for sy in (-1, 1)],
    ],
    "table": [
        (0, 0, 0.92, 1, 1, 0.08, None, 0),
        *[
            (sx * 0.44, sy * 0.45, 0, 0.07, 0.05, 0.92, "dark", 0)
            for sx in (-1, 1)
            for sy in (-1, 1)
        ],
    ],
    "door": [
        (0, 0, 0, 1, 1, 1, None, 0),
        (0.6, 0, 0, 0.4, 1.08, 0.02, (40, 40, 40), 1),
        (0.6, 0.36, 0.48, 2.0, 0.1, 0.03, (40, 190, 210), 1),
    ],
    "window": [
        (0, 0, 0, 1, 1, 1, None, 0),
        (0.6, 0, 0, 0.6, 1, 0.06, (240, 240, 240), 1),
        (0.6, 0, 0.94, 0.6, 1, 0.06, (240, 240, 240), 1),
        (0.6, -0.47, 0, 0.6, 0.06, 1, (240, 240, 240), 1),
        (0.6, 0.47, 0, 0.6, 0.06, 1, (240, 240, 240), 1),
        (0.6, 0, 0, 0.6, 0.04, 1, (240, 240, 240), 2),
        (0.6, 0, 0.48, 0.6, 1, 0.04, (240, 240, 240), 2),
    ],
    "person": [
        (0, -0.2, 0, 0.6, 0.34, 0.47, _JEANS, 0),
        (0, 0.2, 0, 0.6, 0.34, 0.47, _JEANS, 0),
        (0, 0, 0.47, 0.8, 0.72, 0.36, None, 0),
        (0, -0.44, 0.5, 0.5, 0.16, 0.33, None, 0),
        (0, 0.44, 0.5, 0.5, 0.16, 0.33, None, 0),
        (0, 0, 0.84, 0.7, 0.34, 0.16, _SKIN, 0),
    ],
    "plant": [
        (0, 0, 0, 0.6, 0.6, 0.3, (50, 80, 150), 0),
        (0, 0, 0.3, 1, 1, 0.7, None, 0),
        (0, 0, 0.5, 0.7, 1.15, 0.35, "dark", 0),
    ],
    "sofa": [
        (0, 0, 0, 1, 1, 0.5, None, 0),
        (-0.36, 0, 0.5, 0.28, 1, 0.5, None, 0),
        (0.1, -0.46, 0.5, 0.8, 0.08, 0.25, "dark", 0),
        (0.1, 0.46, 0.5, 0.8, 0.08, 0.25, "dark", 0),
    ],
    "shelf": [
        (-0.45, 0, 0, 0.1, 1, 1, "dark", 0),
        (0, -0.47, 0, 1, 0.06, 1, None, 0),
        (0, 0.47, 0, 1, 0.06, 1, None, 0),
        *[(0, 0, z, 1, 0.9, 0.03, None, 0) for z in (0.0, 0.32, 0.64, 0.97)],
        (-0.1, -0.2, 0.03, 0.6, 0.3, 0.22, (40, 40, 180), 0),
        (-0.1, 0.2, 0.35, 0.6, 0.4, 0.2, (160, 80, 30), 0),
        (-0.1, -0.1, 0.67, 0.6, 0.35, 0.24, (40, 150, 60), 0),
    ],
    "lamp": [
        (0, 0, 0, 0.6, 0.6, 0.04, (60, 60, 60), 0),
        (0, 0, 0.04, 0.1, 0.1, 0.7, (60, 60, 60), 0),
        (0, 0, 0.7, 1, 1, 0.3, None, 0),
    ],
    "tree": [
        (0, 0, 0, 0.15, 0.15, 0.4, _WOOD, 0),
        (0, 0, 0.3, 1, 1, 0.7, None, 0),
        (0, 0, 0.45, 0.7, 1.2, 0.4, "dark", 0),
    ],
    "car": [
        (0, 0, 0.15, 1, 1, 0.4, None, 0),
        (-0.05, 0, 0.55, 0.5, 0.9, 0.45, _GLASS_DARK, 0),
        *[
            (sx * 0.32, sy * 0.45, 0, 0.16, 0.12, 0.3, (30, 30, 30), 0)
            for sx in (-1, 1)
            for sy in (-1, 1)
        ],
    ],
}

# Static light: direction towards the light (map frame) and ambient share.
_LIGHT = np.array([0.35, 0.55, 0.76]) / np.linalg.norm([0.35, 0.55, 0.76])
_AMBIENT = 0.62

# Quads of the cube [-1, 1]^3 (scaled by half-sizes) with outward normals, vertices in order.
_CUBE_FACES = [
    ((1, 0, 0), [(1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)]),
    ((-1, 0, 0), [(-1, 1, -1), (-1, -1, -1), (-1, -1, 1), (-1, 1, 1)]),
    ((0, 1, 0), [(1, 1, -1), (-1, 1, -1), (-1, 1, 1), (1, 1, 1)]),
    ((0, -1, 0), [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)]),
    ((0, 0, 1), [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]),
    ((0, 0, -1), [(-1, 1, -1), (1, 1, -1), (1, -1, -1), (-1, -1, -1)]),
]


_CUBE_N = np.array([n for n, _ in _CUBE_FACES], float)
_CUBE_V = np.array([v for _, v in _CUBE_FACES], float)


def _shade(bgr: Any, normal: np.ndarray) -> np.ndarray:
    k = _AMBIENT + (1.0 - _AMBIENT) * max(0.0, float(normal @ _LIGHT))
    return np.clip(np.asarray(bgr, float) * k, 0, 255)


def _bgr_tuple(c: np.ndarray) -> tuple[float, float, float]:
    return (float(c[0]), float(c[1]), float(c[2]))


def _object_quads(obj: SceneObject) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """(verts (4,3), normal, colour, layer) for every face of the object's cuboids."""
    w, d, h = obj.size
    c, s = math.cos(obj.yaw_rad), math.sin(obj.yaw_rad)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    base = np.asarray(obj.position, float)
    normals = _CUBE_N @ rot.T  # (6, 3)
    k = _AMBIENT + (1.0 - _AMBIENT) * np.clip(normals @ _LIGHT, 0.0, None)
    out: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]] = []
    for px, py, pz, dx, dy, dz, colour, layer in _SHAPES.get(obj.kind, _SHAPES["box"]):
        if colour is None:
            col = np.asarray(obj.bgr, float)
        elif colour == "dark":
            col = np.asarray(obj.bgr, float) * 0.55
        else:
            col = np.asarray(colour, float)
        centre = np.array([px * d, py * w, (pz + dz / 2.0) * h])
        half = np.array([dx * d, dy * w, dz * h]) / 2.0
        verts = (_CUBE_V * half + centre) @ rot.T + base  # (6, 4, 3)
        cols = np.clip(col[None, :] * k[:, None], 0, 255)
        out.extend((verts[f], normals[f], cols[f], layer) for f in range(6))
    return out


@functools.lru_cache(maxsize=4)
def _radial(w: int, h: int) -> np.ndarray:
    """Normalised squared radius, 0 at the image centre and 1 in the corners (float32)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2
    out: np.ndarray = np.clip(r2 / 2.0, 0, 1).astype(np.float32)
    out.setflags(write=False)
    return out


@functools.lru_cache(maxsize=64)
def _noise_pattern(
    seed: int, index: int, sigma: float, vignette: float, w: int, h: int
) -> tuple[np.ndarray, np.ndarray]:
    """(add, subtract) uint8 images: Gaussian sensor noise minus lens vignetting (falloff of
    ``vignette`` grey levels in the corners). Built on first use and shared read-only, so a
    renderer that draws one frame pays for one pattern."""
    rng = np.random.default_rng((seed & 0xFFFFFFFF, index))
    total = np.float32(-vignette) * _radial(w, h)
    if sigma > 0:
        total = total + rng.standard_normal((h, w), dtype=np.float32) * np.float32(sigma)
    pos = cv2.cvtColor(np.clip(total, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    neg = cv2.cvtColor(np.clip(-total, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    pos.setflags(write=False)
    neg.setflags(write=False)
    return pos, neg


@functools.lru_cache(maxsize=512)
def _marker_texture(marker_id: int, cell_px: int) -> np.ndarray:
    """BGR texture of a DICT_4X4_50 marker with a one-cell white quiet zone (8×8 cells)."""
    aruco = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    img = cv2.aruco.generateImageMarker(aruco, marker_id, 6 * cell_px, borderBits=1)
    img = cv2.copyMakeBorder(
        img, cell_px, cell_px, cell_px, cell_px, cv2.BORDER_CONSTANT, value=255
    )
    # paper is not perfectly white, ink not perfectly black
    img = (img.astype(np.float32) * (232.0 - 22.0) / 255.0 + 22.0).astype(np.uint8)
    tex = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    tex.setflags(write=False)
    return tex


_MARKER_CELLS = (4, 8, 16, 32, 64)
_MARKER_BACK = (175.0, 178.0, 180.0)


@dataclass(frozen=True)
class Visible:
    """One thing the camera sees (captioner scene graph).

    ``bearing_deg``: horizontal angle from the optical axis to the visible part's centroid,
    positive to the left (REP 103); ``side``: left/ahead/right (±15°); ``near``: closer than
    2.5 m; ``bbox``: (x0, y0, x1, y1) pixels at full resolution; ``area_frac``: visible share
    of the image. Markers have kind ``"marker"``, colour ``"black and white"``, ``marker_id``.
    """

    kind: str
    colour: str
    id: str
    bearing_deg: float
    distance_m: float
    side: Literal["left", "ahead", "right"]
    near: bool
    bbox: tuple[int, int, int, int]
    area_frac: float
    marker_id: int | None = None


NEAR_M = 2.5
SIDE_DEG = 15.0


@dataclass
class _Scene:
    """Precomputed geometry in the map frame (built once per world)."""

    room_faces: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    room_verts: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 3)))
    room_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    room_cols: list[tuple[float, float, float]] = field(default_factory=list)
    colour_tuples: list[tuple[float, float, float]] = field(default_factory=list)
    seg: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    seg_col: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 3)))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colours: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    layer: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    owner: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    obj_centre: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    obj_radius: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mk_outer: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 3)))
    mk_inner: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 3)))
    mk_normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    mk_ids: tuple[int, ...] = ()
    mk_centre: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    face_centre: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def _build_scene(world: World) -> _Scene:
    sc = _Scene()
    b = world.bounds
    surf = world.surfaces
    segs: list[tuple[tuple[float, float, float], tuple[float, float, float]]] = []
    seg_cols: list[np.ndarray] = []

    def quad(
        pts: list[tuple[float, float, float]], n: tuple[float, float, float], bgr: Any
    ) -> None:
        nv = np.asarray(n, float)
        sc.room_faces.append((np.asarray(pts, float), nv, _shade(bgr, nv)))

    floor_col = np.asarray(surf.floor, float)
    if world.indoor:
        x0, x1, y0, y1, z0, z1 = b.x_min, b.x_max, b.y_min, b.y_max, b.z_min, b.z_max
        quad([(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)], (0, 0, 1), surf.floor)
        quad([(x0, y0, z1), (x0, y1, z1), (x1, y1, z1), (x1, y0, z1)], (0, 0, -1), surf.ceiling)
        wall = np.asarray(surf.walls, float)
        dado = wall * 0.8  # lower wall band, a darker tint: gives the walls some structure
        zd = min(z0 + 0.9, z1)
        walls = [
            ((x0, y0), (x1, y0), (0, 1, 0)),
            ((x1, y0), (x1, y1), (-1, 0, 0)),
            ((x1, y1), (x0, y1), (0, -1, 0)),
            ((x0, y1), (x0, y0), (1, 0, 0)),
        ]
        for (ax, ay), (bx, by), n in walls:
            quad([(ax, ay, zd), (bx, by, zd), (bx, by, z1), (ax, ay, z1)], n, wall)
            quad([(ax, ay, z0), (bx, by, z0), (bx, by, zd), (ax, ay, zd)], n, dado)
            segs.append(((ax, ay, zd), (bx, by, zd)))
            seg_cols.append(_shade(wall * 0.55, np.asarray(n, float)))
            segs.append(((ax, ay, z0), (bx, by, z0)))
            seg_cols.append(np.array([40.0, 40.0, 40.0]))
            segs.append(((ax, ay, z0), (ax, ay, z1)))
            seg_cols.append(_shade(wall * 0.7, np.asarray(n, float)))
        # ceiling light panels (slightly below the ceiling so they are drawn over it)
        for lx in np.arange(x0 + 2.0, x1 - 1.0, 2.0):
            for ly in (y0 + (y1 - y0) / 3, y0 + 2 * (y1 - y0) / 3):
                e = 0.3
                zc = z1 - 0.005
                sc.room_faces.append(
                    (
                        np.array(
                            [
                                (lx - e, ly - e, zc),
                                (lx - e, ly + e, zc),
                                (lx + e, ly + e, zc),
                                (lx + e, ly - e, zc),
                            ]
                        ),
                        np.array([0.0, 0.0, -1.0]),
                        np.array([252.0, 252.0, 252.0]),
                    )
                )
        gx0, gx1, gy0, gy1 = x0, x1, y0, y1
    else:
        big = 3000.0
        quad(
            [(-big, -big, 0), (big, -big, 0), (big, big, 0), (-big, big, 0)], (0, 0, 1), surf.floor
        )
        gx0, gx1, gy0, gy1 = b.x_min, b.x_max, b.y_min, b.y_max
    # floor tiles / field grid
    tile = surf.tile_m
    grid_col = _shade(floor_col * 0.7, np.array([0.0, 0.0, 1.0]))
    for gx in np.arange(math.ceil(gx0 / tile) * tile, gx1 + 1e-9, tile):
        if gx0 < gx < gx1 or not world.indoor:
            segs.append(((gx, gy0, b.z_min + 0.001), (gx, gy1, b.z_min + 0.001)))
            seg_cols.append(grid_col)
    for gy in np.arange(math.ceil(gy0 / tile) * tile, gy1 + 1e-9, tile):
        if gy0 < gy < gy1 or not world.indoor:
            segs.append(((gx0, gy, b.z_min + 0.001), (gx1, gy, b.z_min + 0.001)))
            seg_cols.append(grid_col)
    sc.seg = np.asarray(segs, float).reshape(-1, 2, 3)
    sc.room_verts = np.asarray([f[0] for f in sc.room_faces], float).reshape(-1, 4, 3)
    sc.room_normals = np.asarray([f[1] for f in sc.room_faces], float).reshape(-1, 3)
    sc.room_cols = [_bgr_tuple(f[2]) for f in sc.room_faces]
    sc.seg_col = np.asarray(seg_cols, float).reshape(-1, 3)

    faces, normals, colours, layers, owners, centres, radii = [], [], [], [], [], [], []
    for k, obj in enumerate(world.objects):
        quads = _object_quads(obj)
        allv = np.concatenate([q[0] for q in quads])
        lo, hi = allv.min(axis=0), allv.max(axis=0)
        centres.append((lo + hi) / 2.0)
        radii.append(float(np.linalg.norm(hi - lo) / 2.0))
        for verts, fnorm, fcol, layer in quads:
            faces.append(verts)
            normals.append(fnorm)
            colours.append(fcol)
            layers.append(layer)
            owners.append(k)
    if faces:
        sc.faces = np.asarray(faces)
        sc.normals = np.asarray(normals)
        sc.colours = np.asarray(colours)
        sc.layer = np.asarray(layers)
        sc.owner = np.asarray(owners)
        sc.obj_centre = np.asarray(centres)
        sc.obj_radius = np.asarray(radii)
        sc.colour_tuples = [_bgr_tuple(c) for c in colours]
        sc.face_centre = sc.faces.mean(axis=1)
    if world.markers:
        sc.mk_outer = np.asarray([m.corners(margin=m.size_m / 6.0) for m in world.markers])
        sc.mk_inner = np.asarray([m.corners() for m in world.markers])
        sc.mk_normal = np.asarray([m.normal for m in world.markers])
        sc.mk_ids = tuple(m.id for m in world.markers)
        sc.mk_centre = np.asarray([m.position for m in world.markers], float)
    return sc


# ---------------------------------------------------------------------------------------------
# rendering


def _check_non_negative(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")


class Renderer:
    """Renders the world as the front camera sees it from a pose.

    Args:
        world: the world to draw.
        seed: seeds the sensor-noise patterns (the render is deterministic for a seed).
        camera: camera model (default 640×360, 92° diagonal).
        brightness: default lighting factor (1.0 = as designed; 0.5 dim, 1.5 bright).
        noise_sigma: std of the additive per-pixel sensor noise in grey levels (0 = none).
        vignette: darkening of the image corners in grey levels (lens falloff).
        cull: skip objects, faces, lines and markers wholly outside the image before drawing
            (the same pixels, less work); False draws everything, as the reference for tests.

    Raises:
        ValueError: a negative or non-finite brightness, noise_sigma or vignette.
    """

    NEAR_M = 0.03
    MIN_LENS_HEIGHT_M = 0.04
    GUARD = 16.0  # clip polygons to a frustum this many times wider than the image (int32 safe)
    # Culling: what lies wholly beyond one edge of the image by more than this is not drawn. A
    # filled polygon or an anti-aliased 1-px line touches pixels at most ~1.5 px past its
    # outline, so 3 px leaves every drawn pixel as it is (tests/sim/test_render_cull.py).
    CULL_MARGIN_PX = 3.0
    _N_NOISE = 4

    def __init__(
        self,
        world: World,
        seed: int = 0,
        camera: CameraModel | None = None,
        brightness: float = 1.0,
        noise_sigma: float = 2.0,
        vignette: float = 18.0,
        cull: bool = True,
    ) -> None:
        for name, v in (
            ("brightness", brightness),
            ("noise_sigma", noise_sigma),
            ("vignette", vignette),
        ):
            _check_non_negative(name, v)
        self.world = world
        self.cull = cull
        self.camera = camera or CameraModel()
        self.brightness = brightness
        self._scene = _build_scene(world)
        w, h = self.camera.width, self.camera.height
        self._noise_key = (int(seed), float(noise_sigma), float(vignette), w, h)
        sky = np.asarray(world.surfaces.sky if not world.indoor else world.surfaces.walls, np.uint8)
        self._background = np.broadcast_to(sky, (h, w, 3)).copy()
        # frames of a camera that stands still, by (brightness, noise pattern): the render is a
        # pure function of pose, brightness and pattern, so a repeat is a copy, not a redraw
        self._last_pose: tuple[float, ...] | None = None
        self._still_pose: tuple[float, ...] | None = None
        self._still: dict[tuple[float, int], np.ndarray] = {}

    # -- public ---------------------------------------------------------------------------

    def render(self, pose: PoseLike, brightness: float | None = None, frame: int = 0) -> np.ndarray:
        """Render the camera image at ``pose``.

        Args:
            pose: ``(x, y, z, roll, pitch, yaw)`` map frame, radians (or a truth-like object).
            brightness: lighting factor for this frame (default: the renderer's).
            frame: frame counter; selects one of a few sensor-noise patterns.

        Returns:
            (height, width, 3) uint8 BGR image.

        Raises:
            ValueError: malformed pose, negative or non-finite brightness.
        """
        b = self.brightness if brightness is None else brightness
        _check_non_negative("brightness", b)
        pose6 = pose_tuple(pose)
        key = (b, frame % self._N_NOISE)
        if pose6 == self._still_pose:
            kept = self._still.get(key)
            if kept is not None:
                return kept.copy()
        cam = self.camera
        img = self._background.copy()
        self._draw(img, pose6, cam, ids=False)
        seed, sigma, vig, w, h = self._noise_key
        pos, neg = _noise_pattern(seed, key[1], sigma, vig, w, h)
        cv2.add(img, pos, dst=img)
        cv2.subtract(img, neg, dst=img)
        if b != 1.0:
            cv2.convertScaleAbs(img, dst=img, alpha=b)
        if pose6 == self._last_pose:
            # the camera stands still (a landed drone): keep its frames, one per noise pattern
            if pose6 != self._still_pose or len(self._still) >= 2 * self._N_NOISE:
                self._still_pose, self._still = pose6, {}  # bounded: brightness may vary
            self._still[key] = img.copy()
        self._last_pose = pose6
        return img

    def render_ids(self, pose: PoseLike, scale: float = 0.5) -> np.ndarray:
        """Id buffer (uint16): 0 background, 1+k object k, 1+n_objects+j marker j."""
        cam = self.camera.scaled(scale)
        img = np.zeros((cam.height, cam.width), np.uint16)
        self._draw(img, pose, cam, ids=True)
        return img

    def visible(self, pose: PoseLike, min_area_frac: float = 0.0004) -> list[Visible]:
        """What the camera sees at ``pose``: objects and markers, occlusion-aware.

        Sorted by visible area (largest first). Things covering less than ``min_area_frac`` of
        the image are left out.
        """
        scale = 0.5
        ids = self.render_ids(pose, scale)
        cam_s = self.camera.scaled(scale)
        n_obj = len(self.world.objects)
        counts = np.bincount(ids.ravel(), minlength=1 + n_obj + len(self.world.markers))
        total = ids.size
        _, cam_pos = self.camera.camera_in_map(pose)
        out: list[Visible] = []
        for idx in np.nonzero(counts[1:] >= max(1, min_area_frac * total))[0]:
            k = int(idx) + 1
            ys, xs = np.nonzero(ids == k)
            u_mean = float(xs.mean())
            bearing = math.degrees(math.atan2(cam_s.cx - u_mean, cam_s.fx))
            side: Literal["left", "ahead", "right"] = (
                "left" if bearing > SIDE_DEG else "right" if bearing < -SIDE_DEG else "ahead"
            )
            f = 1.0 / scale
            bbox = (
                int(xs.min() * f),
                int(ys.min() * f),
                math.ceil((xs.max() + 1) * f) - 1,
                math.ceil((ys.max() + 1) * f) - 1,
            )
            if k <= n_obj:
                o = self.world.objects[k - 1]
                dist = float(np.linalg.norm(np.asarray(o.centre) - cam_pos))
                kind, colour, oid, mid = o.kind, o.colour, o.id, None
            else:
                m: Marker = self.world.markers[k - 1 - n_obj]
                dist = float(np.linalg.norm(np.asarray(m.position) - cam_pos))
                kind, colour, oid, mid = "marker", "black and white", str(m.id), m.id
            out.append(
                Visible(
                    kind=kind,
                    colour=colour,
                    id=oid,
                    bearing_deg=bearing,
                    distance_m=dist,
                    side=side,
                    near=dist < NEAR_M,
                    bbox=bbox,
                    area_frac=float(counts[k]) / total,
                    marker_id=mid,
                )
            )
        out.sort(key=lambda v: -v.area_frac)
        return out

    # -- internals --------------------------------------------------------------------------

    def _draw(self, img: np.ndarray, pose: PoseLike, cam: CameraModel, ids: bool) -> None:
        sc = self._scene
        x, y, z, roll, pitch, yaw = pose_tuple(pose)
        # a landed AR.Drone's lens is a few cm above the floor; with the lens exactly on the
        # floor plane the floor would be edge-on and vanish from the image
        z = max(z, self.world.bounds.z_min + self.MIN_LENS_HEIGHT_M)
        r, t = cam.map_to_camera((x, y, z, roll, pitch, yaw))
        cam_pos = -r.T @ t
        fx, fy, cx, cy = cam.fx, cam.fy, cam.cx, cam.cy
        gx = self.GUARD * (cam.width / 2.0) / fx
        gy = self.GUARD * (cam.height / 2.0) / fy
        planes = np.array(
            [
                [0.0, 0.0, 1.0, -self.NEAR_M],
                [-1.0, 0.0, gx, 0.0],
                [1.0, 0.0, gx, 0.0],
                [0.0, -1.0, gy, 0.0],
                [0.0, 1.0, gy, 0.0],
            ]
        )
        if self.cull:
            planes = np.concatenate([planes, _view_planes(cam, self.CULL_MARGIN_PX)])
        kmat = (fx, fy, cx, cy)

        # 1. room surfaces and ground (all front-facing from inside a convex room)
        if len(sc.room_verts):
            front = np.einsum("ij,ij->i", sc.room_normals, cam_pos - sc.room_verts[:, 0]) > 0
            idx = np.nonzero(front)[0]
            room_cols: list[Any] = [0] * len(idx) if ids else [sc.room_cols[i] for i in idx]
            _fill_many(img, sc.room_verts[idx] @ r.T + t, room_cols, planes, kmat)

        # 2. floor tiles and room edges
        if not ids and len(sc.seg):
            _draw_segments(img, sc.seg @ r.T + t, sc.seg_col, planes, kmat)

        # 3. markers and objects: painter's algorithm over both, far to near by centre distance
        #    (a wall marker is behind anything standing in front of it; a marker on a post is
        #    ordered like an object). Within an object: by layer, then far faces first; back
        #    faces culled.
        n_obj = len(self.world.objects)
        mk_order: list[tuple[float, int]] = []
        if len(sc.mk_ids):
            mk_dist = np.linalg.norm(sc.mk_centre - cam_pos, axis=1)
            mk_order = sorted(((float(mk_dist[j]), j) for j in range(len(sc.mk_ids))), reverse=True)

        order = np.zeros(0, int)
        face_obj_dist = np.zeros(0)
        if len(sc.faces):
            oc = sc.obj_centre @ r.T + t
            rad = sc.obj_radius
            obj_ok = (
                (oc[:, 2] + rad > self.NEAR_M)
                & (np.abs(oc[:, 0]) - rad * 1.5 < gx * (oc[:, 2] + rad))
                & (np.abs(oc[:, 1]) - rad * 1.5 < gy * (oc[:, 2] + rad))
            )
            if self.cull:
                # bounding sphere wholly outside one side of the image's frustum: not drawn
                view = planes[_N_CLIP:, :3]
                dist = oc @ (view / np.linalg.norm(view, axis=1)[:, None]).T
                obj_ok &= (dist >= -rad[:, None]).all(axis=1)
            front = np.einsum("ij,ij->i", sc.normals, cam_pos - sc.face_centre) > 1e-9
            sel = np.nonzero(front & obj_ok[sc.owner])[0]
            obj_dist = np.linalg.norm(oc, axis=1)
            face_dist = np.linalg.norm(sc.face_centre[sel] - cam_pos, axis=1)
            order = sel[np.lexsort((-face_dist, sc.layer[sel], -obj_dist[sc.owner[sel]]))]
            face_obj_dist = obj_dist[sc.owner[order]]
        pc = sc.faces[order] @ r.T + t
        if ids:
            cols: list[Any] = (sc.owner[order] + 1).tolist()
        else:
            cols = [sc.colour_tuples[i] for i in order]

        # markers entirely behind the camera or outside the guard frustum are skipped up front
        if mk_order:
            mk_pc = sc.mk_outer @ r.T + t  # (Nm, 4, 3)
            d = mk_pc @ planes[:, :3].T + planes[:, 3]
            mk_out = (d < 0).all(axis=1).any(axis=1)
            mk_order = [(dist, j) for dist, j in mk_order if not mk_out[j]]
        done = 0
        for dist, j in mk_order:
            # faces of objects farther than this marker go first (face_obj_dist is descending)
            upto = int(np.searchsorted(-face_obj_dist, -dist, side="right"))
            if upto > done:
                _fill_many(img, pc[done:upto], cols[done:upto], planes, kmat)
                done = upto
            self._draw_one_marker(img, j, r, t, cam_pos, planes, kmat, ids, n_obj)
        if done < len(order):
            _fill_many(img, pc[done:], cols[done:], planes, kmat)

    def _draw_one_marker(
        self,
        img: np.ndarray,
        j: int,
        r: np.ndarray,
        t: np.ndarray,
        cam_pos: np.ndarray,
        planes: np.ndarray,
        kmat: tuple[float, float, float, float],
        ids: bool,
        n_obj: int,
    ) -> None:
        sc = self._scene
        if float(sc.mk_normal[j] @ (cam_pos - sc.mk_inner[j, 0])) <= 0:
            # the back of the printed sheet (seen on free-standing posts): hides what is behind
            _fill(img, sc.mk_outer[j] @ r.T + t, planes, kmat, 0 if ids else _MARKER_BACK)
            return
        if ids:
            _fill(img, sc.mk_inner[j] @ r.T + t, planes, kmat, 1 + n_obj + j)
        else:
            _draw_marker(img, sc.mk_ids[j], sc.mk_outer[j] @ r.T + t, kmat)


_SHIFT = 4
_ONE = 1 << _SHIFT
_N_CLIP = 5  # planes[:5] (near + guard band) clip; any further rows (the image's edges) only cull


def _view_planes(cam: CameraModel, margin_px: float) -> np.ndarray:
    """(4, 4) camera-frame planes a·p + d ≥ 0 through the lens bounding what projects within
    ``margin_px`` of the image (pixel centres at integers, the image from -0.5 to w - 0.5)."""
    m = 0.5 + margin_px
    return np.array(
        [
            [cam.fx, 0.0, cam.cx + m, 0.0],
            [-cam.fx, 0.0, cam.width - 1 - cam.cx + m, 0.0],
            [0.0, cam.fy, cam.cy + m, 0.0],
            [0.0, -cam.fy, cam.height - 1 - cam.cy + m, 0.0],
        ]
    )


def _project(pc: np.ndarray, kmat: tuple[float, float, float, float]) -> np.ndarray:
    fx, fy, cx, cy = kmat
    u = fx * pc[:, 0] / pc[:, 2] + cx
    v = fy * pc[:, 1] / pc[:, 2] + cy
    return np.stack([u, v], axis=1)


def _clip(
    poly: list[tuple[float, float, float]], planes: list[tuple[float, float, float, float]]
) -> list[tuple[float, float, float]]:
    """Sutherland–Hodgman clip of a convex polygon against planes a·p + d ≥ 0.

    Plain Python floats: for polygons of 4–8 vertices this is several times faster than numpy.
    """
    for a, b, c, e in planes:
        if not poly:
            return poly
        d = [a * x + b * y + c * z + e for x, y, z in poly]
        if min(d) >= 0:
            continue
        out = []
        n = len(poly)
        for i in range(n):
            j = i + 1 if i + 1 < n else 0
            dp, dq = d[i], d[j]
            p = poly[i]
            if dp >= 0:
                out.append(p)
            if (dp >= 0) != (dq >= 0):
                q = poly[j]
                k = dp / (dp - dq)
                out.append(
                    (p[0] + (q[0] - p[0]) * k, p[1] + (q[1] - p[1]) * k, p[2] + (q[2] - p[2]) * k)
                )
        poly = out
    return poly


def _fill(
    img: np.ndarray,
    pc: np.ndarray,
    planes: np.ndarray,
    kmat: tuple[float, float, float, float],
    colour: Any,
) -> None:
    """Fill a convex camera-frame polygon, clipping only when it leaves the guard frustum."""
    d = pc @ planes[:, :3].T + planes[:, 3]
    if (d < 0).all(axis=0).any():
        return  # entirely outside one plane
    if (d[:, :_N_CLIP] < 0).any():
        clip_planes = [tuple(p) for p in planes[:_N_CLIP].tolist()]
        poly = _clip([tuple(v) for v in pc.tolist()], clip_planes)
        if len(poly) < 3:
            return
        fx, fy, cx, cy = kmat
        pts = np.array(
            [
                (round((fx * x / z + cx) * _ONE), round((fy * y / z + cy) * _ONE))
                for x, y, z in poly
            ],
            np.int32,
        )
    else:
        pts = np.round(_project(pc, kmat) * _ONE).astype(np.int32)
    cv2.fillConvexPoly(img, pts, colour, lineType=cv2.LINE_8, shift=_SHIFT)


def _fill_many(
    img: np.ndarray,
    pcs: np.ndarray,
    colours: Sequence[Any],
    planes: np.ndarray,
    kmat: tuple[float, float, float, float],
) -> None:
    """Fill (N, 4, 3) camera-frame quads in order: classify and project them all at once, clip
    only the few that leave the guard frustum (the per-polygon Python work is the bottleneck)."""
    if not len(pcs):
        return
    d = pcs @ planes[:, :3].T + planes[:, 3]  # (N, 4, planes)
    out = d < 0
    reject = out.all(axis=1).any(axis=1)
    keep = np.nonzero(~reject)[0]
    if not len(keep):
        return
    pcs = pcs[keep]
    clip = out[keep, :, :_N_CLIP].any(axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(clip[:, None], 1.0, pcs[..., 2])
        fx, fy, cx, cy = kmat
        u = fx * pcs[..., 0] / z + cx
        v = fy * pcs[..., 1] / z + cy
    pts = np.round(np.stack([u, v], axis=-1) * _ONE).astype(np.int32)
    for k, i, c in zip(range(len(keep)), keep.tolist(), clip.tolist(), strict=True):
        if c:
            _fill(img, pcs[k], planes, kmat, colours[i])
        else:
            cv2.fillConvexPoly(img, pts[k], colours[i], cv2.LINE_8, _SHIFT)


def _draw_segments(
    img: np.ndarray,
    seg: np.ndarray,
    cols: np.ndarray,
    planes: np.ndarray,
    kmat: tuple[float, float, float, float],
) -> None:
    """Clip (N, 2, 3) camera-frame segments to the guard frustum (Liang–Barsky) and draw the
    ones not wholly beyond an image edge (``planes[_N_CLIP:]``), in the same colour order."""
    a = seg[:, 0].copy()
    b = seg[:, 1].copy()
    keep = np.ones(len(seg), bool)
    for plane in planes[:_N_CLIP]:
        da = a @ plane[:3] + plane[3]
        db = b @ plane[:3] + plane[3]
        keep &= ~((da < 0) & (db < 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            tcut = np.where(da != db, da / (da - db), 0.0)[:, None]
        cut = a + (b - a) * tcut
        a = np.where(((da < 0) & (db >= 0))[:, None], cut, a)
        b = np.where(((db < 0) & (da >= 0))[:, None], cut, b)
    seen = keep.copy()
    for plane in planes[_N_CLIP:]:
        seen &= ~(((a @ plane[:3] + plane[3]) < 0) & ((b @ plane[:3] + plane[3]) < 0))
    idx = np.nonzero(keep)[0]
    if not len(idx):
        return
    # one polylines call per colour (the grid shares one colour): far fewer calls than lines.
    # Colours are drawn in the order of their first line in the guard band, seen or not, so
    # that where lines of two colours cross the later colour is on top as without culling.
    groups: dict[tuple[float, float, float], list[int]] = {}
    for i, c, s in zip(
        idx.tolist(), map(tuple, cols[idx].tolist()), seen[idx].tolist(), strict=True
    ):
        lines = groups.setdefault(c, [])
        if s:
            lines.append(i)
    drawn = np.nonzero(seen)[0]
    if not len(drawn):
        return
    ua = _project(a[drawn], kmat)
    ub = _project(b[drawn], kmat)
    pairs = np.round(np.stack([ua, ub], axis=1) * _ONE).astype(np.int32)  # (n, 2, 2)
    row = {int(i): k for k, i in enumerate(drawn.tolist())}
    for c, members in groups.items():
        if members:
            cv2.polylines(img, [pairs[row[i]] for i in members], False, c, 1, cv2.LINE_AA, _SHIFT)


def _draw_marker(
    img: np.ndarray, marker_id: int, pc: np.ndarray, kmat: tuple[float, float, float, float]
) -> None:
    """Warp the marker bitmap (with quiet zone) onto its exact projected quad, ROI only."""
    if (pc[:, 2] <= Renderer.NEAR_M).any():
        return  # partly behind the camera: skipped (it would fill the view edge anyway)
    uv = _project(pc, kmat)
    h, w = img.shape[:2]
    x0 = max(math.floor(uv[:, 0].min()), 0)
    y0 = max(math.floor(uv[:, 1].min()), 0)
    x1 = min(math.ceil(uv[:, 0].max()) + 1, w)
    y1 = min(math.ceil(uv[:, 1].max()) + 1, h)
    if x1 <= x0 or y1 <= y0:
        return
    edge = float(np.max(np.linalg.norm(uv - uv[[3, 0, 1, 2]], axis=1)))
    cell = next((c for c in _MARKER_CELLS if 8 * c >= edge), _MARKER_CELLS[-1])
    tex = _marker_texture(marker_id, cell)
    ts = tex.shape[0]
    # texture pixel centres are integers, so its outer edges are at -0.5 and ts - 0.5
    src = np.array(
        [[-0.5, -0.5], [ts - 0.5, -0.5], [ts - 0.5, ts - 0.5], [-0.5, ts - 0.5]], np.float32
    )
    dst = (uv - np.array([x0, y0])).astype(np.float32)
    hmat = cv2.getPerspectiveTransform(src, dst)
    roi = img[y0:y1, x0:x1]
    cv2.warpPerspective(
        tex,
        hmat,
        (x1 - x0, y1 - y0),
        dst=roi,
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_TRANSPARENT,
    )


@functools.lru_cache(maxsize=8)
def _renderer_for(world: World) -> Renderer:
    return Renderer(world, noise_sigma=0.0, vignette=0.0)


def visible_objects(world: World, pose: PoseLike, min_area_frac: float = 0.0004) -> list[Visible]:
    """The captioner's scene graph: objects and markers visible from ``pose`` (see
    :meth:`Renderer.visible`). Renderers are cached per world (worlds are frozen/hashable)."""
    return _renderer_for(world).visible(pose, min_area_frac)
