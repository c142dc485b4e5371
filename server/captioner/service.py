"""What the dialog, REST, ``/console/describe`` and the task manager call: never raise, always a
sentence (the caption, or why there is none)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from server.captioner.errors import BadFrame, CaptionerUnavailable
from server.captioner.model import DEFAULT_BEAM, Caption, Captioner

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


async def describe_frame(
    captioner: Captioner | CaptionerUnavailable | None, frame: Any, *, beam: int = DEFAULT_BEAM
) -> str:
    """Caption ``frame`` (BGR array or JPEG bytes) in the captioner's worker thread.

    Returns the caption, or a sentence saying why there is none (no model and why, no frame,
    unusable frame, or the model found nothing to say). The event loop is never blocked.
    """
    return (await describe_timed(captioner, frame, beam=beam))[0]


async def describe_timed(
    captioner: Captioner | CaptionerUnavailable | None, frame: Any, *, beam: int = DEFAULT_BEAM
) -> tuple[str, float | None]:
    """:func:`describe_frame` plus the captioning time in ms (None when nothing was captioned),
    for ``POST /api/v1/drones/{id}/describe`` (``{drone, text, ms}``)."""
    early = _precheck(captioner, frame)
    if early is not None:
        return early, None
    assert isinstance(captioner, Captioner)
    try:
        caption = await captioner.describe(frame, beam=beam)
    except BadFrame as exc:
        return f"I cannot describe this camera image: {exc}.", None
    return _text(caption), caption.ms


def describe_frame_sync(
    captioner: Captioner | CaptionerUnavailable | None, frame: Any, *, beam: int = DEFAULT_BEAM
) -> str:
    """:func:`describe_frame` in the caller's thread (lockstep runs, the task manager's hook)."""
    early = _precheck(captioner, frame)
    if early is not None:
        return early
    assert isinstance(captioner, Captioner)
    try:
        return _text(captioner.caption(frame, beam=beam))
    except BadFrame as exc:
        return f"I cannot describe this camera image: {exc}."
