"""Scene description: an ONNX image captioner (CNN encoder -> LSTM decoder, Show and Tell).

Public API::

    Captioner.load(model_dir) -> Captioner          # raises CaptionerUnavailable(reason)
    captioner.caption(frame, beam=3, max_len=24) -> Caption(text, tokens, score, ms)
    await captioner.describe(frame, ...) -> Caption # in the captioner's worker thread
    load_captioner(model_dir) -> Captioner | CaptionerUnavailable   # never raises
    await describe_frame(captioner_or_unavailable, frame) -> str     # a sentence for people
    describe_frame_sync(captioner_or_unavailable, frame) -> str      # same, caller's thread
    await describe_timed(captioner_or_unavailable, frame) -> (str, ms | None)
"""

from server.captioner.errors import BadFrame, CaptionerError, CaptionerUnavailable
from server.captioner.model import Caption, Captioner
from server.captioner.service import (
    describe_frame,
    describe_frame_sync,
    describe_timed,
    load_captioner,
)

__all__ = [
    "BadFrame",
    "Caption",
    "Captioner",
    "CaptionerError",
    "CaptionerUnavailable",
    "describe_frame",
    "describe_frame_sync",
    "describe_timed",
    "load_captioner",
]
