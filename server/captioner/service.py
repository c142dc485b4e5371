"""What the dialog, REST, ``/console/describe`` and the task manager call: never raise, always a
sentence (the description, or why there is none).

A description is the captioner's sentence checked against the image (:func:`ground`): its
kinds are kept only where a region of the image supports them, colours are the regions' own,
markers are the ArUco detector's with their ids, and what nothing supports is left out."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from server.captioner.errors import BadFrame, CaptionerUnavailable
from server.captioner.grounding import SeenMarker, ground_marker_ids, ground_objects, sentence
from server.captioner.markers import MarkerDetector
from server.captioner.model import DEFAULT_BEAM, Caption, Captioner, as_bgr
from server.captioner.scene import parse

log = logging.getLogger(__name__)

NO_FRAME = "I have no camera image to describe yet."
NOTHING = "I cannot tell what is in view."


def load_captioner(model_dir: str | Path) -> Captioner | CaptionerUnavailable:
    """Load the captioner, or return (and log once) why scene description is unavailable."""
    try:
        return Captioner.load(model_dir)
    except CaptionerUnavailable as exc:
        log.warning("scene description unavailable: %s", exc.reason)
        return exc


def unavailable_text(reason: str) -> str:
    """The sentence shown and spoken when the captioner could not be loaded."""
    return f"Scene description is unavailable: {reason}"


def _precheck(captioner: Captioner | CaptionerUnavailable | None, frame: Any) -> str | None:
    if captioner is None:
        return unavailable_text("no captioner model was loaded")
    if isinstance(captioner, CaptionerUnavailable):
        return unavailable_text(captioner.reason)
    if frame is None:
        return NO_FRAME
    return None


def _text(caption: Caption) -> str:
    return caption.text or NOTHING


def ground(
    captioner: Captioner,
    frame: Any,
    *,
    beam: int = DEFAULT_BEAM,
    markers: Sequence[SeenMarker] = (),
) -> Caption:
    """Describe ``frame`` in words the image supports (a :class:`Caption` whose ``text`` is the
    grounded sentence and ``ms`` the whole time taken).

    Markers come from the ArUco detector on this frame (ids exact), plus ``markers`` the
    vehicle's own perception reports (a frame with the tracking overlay drawn over its markers
    may hide them from a second detector); the captioner's kinds are
    checked against the regions of the image (``server.captioner.scene``) and take their colour
    and side from them. Without the region classifier (no ``regions.json``) the captioner's
    sentence is kept, its marker ids grounded.

    Raises:
        BadFrame: the frame is not a usable image.
    """
    start = time.perf_counter()
    image = as_bgr(frame)
    caption = captioner.caption(image, beam=beam)
    found = MarkerDetector().detect(image)
    seen = [m.seen() for m in found]
    seen += [m for m in markers if m.id not in {s.id for s in seen}]
    if captioner.regions is None:
        text = ground_marker_ids(_text(caption), seen)
    else:
        scene = parse(image, captioner.regions, [m.box for m in found])
        text = sentence(ground_objects(caption.text, scene.regions), seen)
    ms = (time.perf_counter() - start) * 1000.0
    return Caption(text, caption.tokens, caption.score, ms)


async def describe_frame(
    captioner: Captioner | CaptionerUnavailable | None,
    frame: Any,
    *,
    beam: int = DEFAULT_BEAM,
    markers: Sequence[SeenMarker] = (),
) -> str:
    """Caption ``frame`` (BGR array or JPEG bytes) in the captioner's worker thread.

    Returns the caption, or a sentence saying why there is none (no model and why, no frame,
    unusable frame, or the model found nothing to say). The event loop is never blocked.
    """
    return (await describe_timed(captioner, frame, beam=beam, markers=markers))[0]


async def describe_timed(
    captioner: Captioner | CaptionerUnavailable | None,
    frame: Any,
    *,
    beam: int = DEFAULT_BEAM,
    markers: Sequence[SeenMarker] = (),
) -> tuple[str, float | None]:
    """:func:`describe_frame` plus the time taken in ms (None when nothing was described),
    for ``POST /api/v1/drones/{id}/describe`` (``{drone, text, ms}``); ``markers``: what the
    vehicle's perception sees now (see :func:`ground`)."""
    early = _precheck(captioner, frame)
    if early is not None:
        return early, None
    assert isinstance(captioner, Captioner)
    try:
        caption = await captioner.run(lambda: ground(captioner, frame, beam=beam, markers=markers))
    except BadFrame as exc:
        return f"I cannot describe this camera image: {exc}.", None
    return caption.text, caption.ms


def describe_frame_sync(
    captioner: Captioner | CaptionerUnavailable | None,
    frame: Any,
    *,
    beam: int = DEFAULT_BEAM,
    markers: Sequence[SeenMarker] = (),
) -> str:
    """:func:`describe_frame` in the caller's thread (lockstep runs, the task manager's hook)."""
    early = _precheck(captioner, frame)
    if early is not None:
        return early
    assert isinstance(captioner, Captioner)
    try:
        return ground(captioner, frame, beam=beam, markers=markers).text
    except BadFrame as exc:
        return f"I cannot describe this camera image: {exc}."
