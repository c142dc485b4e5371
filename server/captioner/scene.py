"""What the image itself shows: coloured regions, their colour names, sides and likely kinds.

The simulator draws flat-shaded objects in a small palette of paints; shading and exposure scale
a surface's R, G and B together, so its hue and saturation stay those of its paint while its
brightness varies. Each pixel (at 320×180, after a 3×3 median against sensor noise) is named by
the nearest paint in hue–saturation (brightness only breaks ties between paints of one hue,
such as orange and brown); near-grey pixels are dark ("black") or background (walls, ceiling,
light panels). Floor tan, grass and sky are named too, so that they are never taken for objects.

Candidate objects are the connected regions of one paint, and the flat faces (bounded by
edges) of the grey background that are not wall-sized: white or grey by their brightness
against the frame's brightest grey surfaces. A region's kind comes from a small classifier
(:class:`RegionClassifier`, one hidden layer) on its shape (box, fill, row and column profiles,
Hu moments), brightness and the paints around it (skin above and dark blue below a shirt is a
person, a brown stem below green is a tree), trained on simulator renders by
``tools/train_scene_regions.py``; it may also say "none" (a wall face, a part of another
object). Nothing here reads the simulator's scene: only pixels.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from drone.camera import CameraModel

WORK_W, WORK_H = 320, 180
SIDE_DEG = 15.0  # as drone/sim/camera.py labels scenes: beyond ±15° is left or right
MIN_REGION_FRAC = 0.0015  # regions smaller than this share of the image are ignored
CHROMA_MIN = 0.2  # saturation below this is grey (black or background)
BLACK_V = 62.0  # grey pixels darker than this are black paint (walls are ≥ 70 in dim light)
GREY_MAX_FRAC = 0.25  # a flat grey area larger than this is a wall, ceiling or the like
WHITE_RATIO = 0.8  # a grey face this bright against the frame's brightest grey is white

# Paint prototypes: hue (degrees), saturation, brightness of the paint in full light, from the
# simulator's palette (drone/sim/world.py COLOURS) and the fixed parts of its object models
# (drone/sim/camera.py: skin, jeans, car glass, tree wood, plant pot) and surfaces
# (worlds/*.yaml: floor, grass, sky).
PAINTS: dict[str, tuple[float, float, float]] = {
    "red": (0.0, 0.81, 210.0),
    "green": (120.0, 0.71, 170.0),
    "blue": (218.8, 0.85, 200.0),
    "yellow": (53.7, 0.83, 230.0),
    "orange": (28.6, 0.87, 240.0),
    "purple": (288.0, 0.67, 150.0),
    "pink": (333.9, 0.47, 245.0),
    "brown": (26.2, 0.67, 120.0),
    "cyan": (184.0, 0.71, 210.0),
    "light blue": (201.2, 0.36, 235.0),
    "tan": (26.0, 0.41, 170.0),  # floor and skin
    "navy": (213.0, 0.5, 90.0),  # jeans and car glass
    "grass": (97.5, 0.57, 140.0),
}
COLOUR_PAINTS = (
    "red",
    "green",
    "blue",
    "yellow",
    "orange",
    "purple",
    "pink",
    "brown",
    "cyan",
    "light blue",
    "black",
)
"""Paints that are colours of objects (regions of these are candidate objects)."""
GREYS = ("white", "grey")
"""Names of grey regions (faces bounded by edges in the grey background)."""
REGION_COLOURS = (*COLOUR_PAINTS, *GREYS)
CLASSES = ("background", *PAINTS, "black")
BACKGROUND, BLACK = 0, len(CLASSES) - 1
_INDEX = {name: i for i, name in enumerate(CLASSES)}
CUES = ("tan", "navy", "black", "brown", "green", "yellow", "grass", "light blue", "background")
"""Paints whose presence around a region tells its kind (features of the classifier)."""
KINDS = (
    "none",
    "box",
    "car",
    "chair",
    "door",
    "lamp",
    "person",
    "plant",
    "post",
    "shelf",
    "sofa",
    "table",
    "tree",
    "window",
)
"""Classifier outputs: ``none`` (not an object of this paint) and the simulator's object kinds."""


@dataclass(frozen=True)
class Region:
    """A connected region of one paint: colour name, side, image share, bounding box (at
    320×180), bearing (degrees, left positive), kind probabilities (same order as ``KINDS``)."""

    colour: str
    side: str
    area: float
    box: tuple[int, int, int, int]
    bearing_deg: float
    features: tuple[float, ...]
    probs: tuple[float, ...] = ()

    @property
    def kind(self) -> str:
        """The most likely kind (``none`` when there are no probabilities)."""
        return KINDS[int(np.argmax(self.probs))] if self.probs else "none"

    def p(self, kind: str) -> float:
        return self.probs[KINDS.index(kind)] if self.probs else 0.0


@dataclass(frozen=True)
class Parse:
    """Everything found in one frame: per-pixel paint labels, regions, outdoors or not."""

    labels: npt.NDArray[np.uint8]
    regions: tuple[Region, ...]
    masks: tuple[npt.NDArray[np.bool_], ...]  # one per region, same order
    outdoor: bool


def _prototypes() -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], list[int]]:
    vecs, logv, idx = [], [], []
    for name, (h, s, v) in PAINTS.items():
        a = math.radians(h)
        vecs.append((s * math.cos(a), s * math.sin(a)))
        logv.append(math.log(v))
        idx.append(_INDEX[name])
    return np.asarray(vecs, np.float32), np.asarray(logv, np.float32), idx


_PROTO, _PROTO_LOGV, _PROTO_IDX = _prototypes()
_V_WEIGHT = 0.12  # brightness counts little: exposure and shading change it by up to 2×
_V_EXPECT = math.log(0.85)  # the mean of shading (0.62–1) and exposure around 1


def _classify(
    h_deg: npt.NDArray[np.float32], s: npt.NDArray[np.float32], v: npt.NDArray[np.float32]
) -> npt.NDArray[np.uint8]:
    """Paint class of hue (degrees), saturation (0–1) and brightness (0–255) values."""
    h = np.radians(h_deg)
    chroma = np.stack([s * np.cos(h), s * np.sin(h)], axis=-1)
    d = np.linalg.norm(chroma[..., None, :] - _PROTO, axis=-1)
    logv = np.log(np.maximum(v, 1.0))
    d += _V_WEIGHT * np.abs(logv[..., None] - _V_EXPECT - _PROTO_LOGV)
    labels: npt.NDArray[np.uint8] = np.asarray(_PROTO_IDX, np.uint8)[np.argmin(d, axis=-1)]
    grey = s < CHROMA_MIN
    labels[grey] = BACKGROUND
    labels[grey & (v < BLACK_V)] = BLACK
    return labels


@functools.cache
def _lut() -> npt.NDArray[np.uint8]:
    """:func:`_classify` for every OpenCV 8-bit HSV value (H in 2° steps; S and V in steps of
    8 levels), so that a frame costs one table look-up per pixel."""
    h, s, v = np.meshgrid(
        np.arange(180, dtype=np.float32) * 2.0,
        (np.arange(32, dtype=np.float32) * 8.0 + 3.5) / 255.0,
        np.arange(32, dtype=np.float32) * 8.0 + 3.5,
        indexing="ij",
    )
    table = _classify(h.ravel(), s.ravel(), v.ravel())
    table.setflags(write=False)
    return table


def warm_up() -> None:
    """Build the paint look-up table now (a second or so) rather than in the first description."""
    _lut()


def _small(frame_bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """The frame at 320×180 (area average), 3×3 median-filtered against sensor noise."""
    resized = cv2.resize(frame_bgr, (WORK_W, WORK_H), interpolation=cv2.INTER_AREA)
    out: npt.NDArray[np.uint8] = np.asarray(cv2.medianBlur(resized, 3), np.uint8)
    return out


def paint_labels(
    frame_bgr: npt.NDArray[np.uint8], small: npt.NDArray[np.uint8] | None = None
) -> npt.NDArray[np.uint8]:
    """Per-pixel paint class (index into ``CLASSES``) at 320×180 (``small``: the frame already
    resized and median-filtered)."""
    small = _small(frame_bgr) if small is None else small
    hsv = cv2.cvtColor(small, cv2.COLOR_BGR2HSV)
    index = (
        hsv[..., 0].astype(np.int32) * 1024
        + (hsv[..., 1].astype(np.int32) >> 3) * 32
        + (hsv[..., 2].astype(np.int32) >> 3)
    )
    labels: npt.NDArray[np.uint8] = _lut()[index]
    return labels


def _frac(labels: npt.NDArray[np.uint8], box: tuple[int, int, int, int], cue: int) -> float:
    x0, y0, x1, y1 = box
    x0, x1 = max(x0, 0), min(x1, WORK_W)
    y0, y1 = max(y0, 0), min(y1, WORK_H)
    if x1 <= x0 or y1 <= y0:
        return 0.0
    return float(np.mean(labels[y0:y1, x0:x1] == cue))


def region_features(
    labels: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.bool_],
    colour: str,
    box: tuple[int, int, int, int],
    area_px: int,
    outdoor: bool,
    grey: npt.NDArray[np.uint8],
    top: float,
) -> tuple[float, ...]:
    """Shape, colour, brightness and surroundings of a region (the classifier's input).

    ``grey``: the frame's grey levels at 320×180; ``top``: the level of its brightest grey
    surfaces (a region's level against it tells white from grey under any exposure)."""
    x0, y0, x1, y1 = box  # exclusive x1, y1
    w, h = x1 - x0, y1 - y0
    feats: list[float] = [1.0 if colour == c else 0.0 for c in REGION_COLOURS]
    feats += [
        math.log(area_px / (WORK_W * WORK_H)),
        w / WORK_W,
        h / WORK_H,
        math.log(h / w),
        area_px / (w * h),
        (x0 + x1) / 2 / WORK_W,
        y0 / WORK_H,
        y1 / WORK_H,
        float(x0 == 0 or x1 == WORK_W),
        float(y0 == 0),
        float(y1 == WORK_H),
        float(outdoor),
    ]
    # how the region's rows and columns are filled (a table top is wide and thin, a chair's
    # legs leave its lower part sparse, a person's arms widen the middle)
    sub = mask[y0:y1, x0:x1]
    for k in range(_PROFILE_BINS):
        a, b = k / _PROFILE_BINS, (k + 1) / _PROFILE_BINS
        rows = sub[int(a * h) : max(int(b * h), int(a * h) + 1)]
        feats.append(float(rows.mean()) if rows.size else 0.0)
    for k in range(_PROFILE_BINS):
        a, b = k / _PROFILE_BINS, (k + 1) / _PROFILE_BINS
        cols = sub[:, int(a * w) : max(int(b * w), int(a * w) + 1)]
        feats.append(float(cols.mean()) if cols.size else 0.0)
    hu = cv2.HuMoments(cv2.moments(sub.astype(np.uint8), binaryImage=True)).ravel()
    feats += [float(-np.sign(v) * np.log10(abs(v) + 1e-12)) / 10.0 for v in hu[:4]]
    hh, ww = max(h // 2, 2), max(w // 4, 1)
    zones = (
        (x0, y0 - hh, x1, y0),  # above
        (x0, y1, x1, y1 + hh),  # below
        (x0 - ww, y0, x0, y1),  # left
        (x1, y0, x1 + ww, y1),  # right
        (x0, y0, x1, y1),  # inside the box
    )
    for zone in zones:
        for cue in CUES:
            feats.append(_frac(labels, zone, _INDEX[cue]))
    levels = grey[y0:y1, x0:x1][sub]
    level = float(np.median(levels))
    ring = grey[max(y0 - 3, 0) : y1 + 3, max(x0 - 3, 0) : x1 + 3]
    feats += [
        level / 255.0,
        level / max(top, 1.0),
        float(np.std(levels)) / 64.0,  # several faces in different light, or one flat face
        (level - float(np.median(ring))) / 255.0,  # brighter or darker than its surroundings
    ]
    return tuple(feats)


_PROFILE_BINS = 5
N_FEATURES = len(REGION_COLOURS) + 12 + 2 * _PROFILE_BINS + 4 + 5 * len(CUES) + 4


class RegionClassifier:
    """One hidden ReLU layer and a softmax over standardised region features (weights from
    ``regions.json``)."""

    def __init__(
        self,
        mean: npt.NDArray[np.float64],
        scale: npt.NDArray[np.float64],
        w1: npt.NDArray[np.float64],
        b1: npt.NDArray[np.float64],
        w2: npt.NDArray[np.float64],
        b2: npt.NDArray[np.float64],
    ) -> None:
        self.mean, self.scale = mean, scale
        self.w1, self.b1, self.w2, self.b2 = w1, b1, w2, b2

    @classmethod
    def load(cls, path: str | Path) -> RegionClassifier:
        """Read weights written by ``tools/train_scene_regions.py``.

        Raises:
            ValueError: the file is not a region classifier for these features and kinds.
        """
        data = json.loads(Path(path).read_text())
        if data.get("format") != "uav-console-scene-regions/1":
            raise ValueError(f"{path} is not a scene-region classifier")
        if tuple(data["kinds"]) != KINDS or int(data["features"]) != N_FEATURES:
            raise ValueError(f"{path} was trained for other kinds or features")
        mean, scale, w1, b1, w2, b2 = (
            np.asarray(data[k], np.float64) for k in ("mean", "scale", "w1", "b1", "w2", "b2")
        )
        hidden = w1.shape[-1] if w1.ndim == 2 else -1
        shapes_ok = (
            mean.shape == scale.shape == (N_FEATURES,)
            and w1.shape == (N_FEATURES, hidden)
            and b1.shape == (hidden,)
            and w2.shape == (hidden, len(KINDS))
            and b2.shape == (len(KINDS),)
        )
        if not shapes_ok or not all(np.isfinite(a).all() for a in (mean, scale, w1, b1, w2, b2)):
            raise ValueError(f"{path} has weights of the wrong shape or non-finite values")
        return cls(mean, scale, w1, b1, w2, b2)

    def probs(self, features: Sequence[Sequence[float]]) -> npt.NDArray[np.float64]:
        """Kind probabilities ``[N, len(KINDS)]`` for feature rows ``[N, N_FEATURES]``."""
        x = (np.asarray(features, np.float64) - self.mean) / self.scale
        hidden = np.maximum(x @ self.w1 + self.b1, 0.0)
        z = hidden @ self.w2 + self.b2
        z -= z.max(axis=1, keepdims=True)
        e = np.exp(z)
        out: npt.NDArray[np.float64] = e / e.sum(axis=1, keepdims=True)
        return out


_CAMERA = CameraModel().scaled(WORK_W / CameraModel().width)


def parse(
    frame_bgr: npt.NDArray[np.uint8],
    classifier: RegionClassifier | None = None,
    mask_boxes: Sequence[tuple[int, int, int, int]] = (),
) -> Parse:
    """Paint labels and candidate object regions of a frame (any size; worked at 320×180).

    ``mask_boxes`` (full-resolution pixel boxes, e.g. detected markers) are left out of the
    regions: a marker's black squares are not a black object.
    """
    smooth = _small(frame_bgr)
    labels = paint_labels(frame_bgr, smooth)
    fy = WORK_H / frame_bgr.shape[0]
    fx = WORK_W / frame_bgr.shape[1]
    for x0, y0, x1, y1 in mask_boxes:
        pad = 2
        labels[
            max(int(y0 * fy) - pad, 0) : int(y1 * fy) + pad + 1,
            max(int(x0 * fx) - pad, 0) : int(x1 * fx) + pad + 1,
        ] = BACKGROUND
    outdoor = float(np.mean(labels == _INDEX["grass"])) > 0.05
    regions: list[tuple[str, npt.NDArray[np.bool_], tuple[int, int, int, int], int]] = []
    kernel = np.ones((3, 3), np.uint8)
    min_px = MIN_REGION_FRAC * WORK_W * WORK_H
    for colour in COLOUR_PAINTS:
        if outdoor and colour == "light blue":
            continue  # the sky's paint
        mask = (labels == _INDEX[colour]).astype(np.uint8)
        if not mask.any():
            continue
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        for k in range(1, n):
            x, y, w, h, a = (int(v) for v in stats[k])
            if a >= min_px:
                regions.append((colour, comp == k, (x, y, x + w, y + h), a))
    grey: npt.NDArray[np.uint8] = np.asarray(cv2.cvtColor(smooth, cv2.COLOR_BGR2GRAY), np.uint8)
    flat = (labels == BACKGROUND) & (cv2.dilate(cv2.Canny(grey, 12, 30), kernel) == 0)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(flat.astype(np.uint8), connectivity=4)
    background = labels == BACKGROUND
    top = float(np.percentile(grey[background], 99)) if background.any() else 255.0
    for k in range(1, n):
        x, y, w, h, a = (int(v) for v in stats[k])
        if a < min_px or a > GREY_MAX_FRAC * WORK_W * WORK_H:
            continue
        mask = comp == k
        level = float(np.median(grey[mask]))
        colour = "white" if level >= WHITE_RATIO * top else "grey"
        regions.append((colour, mask, (x, y, x + w, y + h), a))
    feats = [region_features(labels, m, c, b, a, outdoor, grey, top) for c, m, b, a in regions]
    probs = classifier.probs(feats) if classifier is not None and feats else None
    out: list[tuple[Region, npt.NDArray[np.bool_]]] = []
    for i, (colour, mask, box, area) in enumerate(regions):
        xs = np.nonzero(mask.any(axis=0))[0]
        cols = mask.sum(axis=0)
        u = float((np.arange(WORK_W) * cols).sum() / max(cols.sum(), 1)) if len(xs) else 0.0
        bearing = math.degrees(math.atan2(_CAMERA.cx - u, _CAMERA.fx))
        side = "left" if bearing > SIDE_DEG else "right" if bearing < -SIDE_DEG else "ahead"
        region = Region(
            colour=colour,
            side=side,
            area=area / (WORK_W * WORK_H),
            box=box,
            bearing_deg=bearing,
            features=feats[i],
            probs=tuple(float(p) for p in probs[i]) if probs is not None else (),
        )
        out.append((region, mask))
    out.sort(key=lambda rm: -rm[0].area)
    return Parse(labels, tuple(r for r, _ in out), tuple(m for _, m in out), outdoor)
