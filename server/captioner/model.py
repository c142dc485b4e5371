"""The captioner at run time: two onnxruntime sessions (encoder, one-step decoder) and a search.

Created once (:meth:`Captioner.load`), then :meth:`Captioner.caption` runs in the caller's thread
and :meth:`Captioner.describe` in the captioner's own single worker thread, so the asyncio loop
never blocks on inference. The ONNX I/O contract is in ``models/captioner/MODEL.md``.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import cv2
import numpy as np
import numpy.typing as npt

from server.captioner.errors import BadFrame, CaptionerUnavailable
from server.captioner.search import Hypothesis, beam_search, greedy
from server.captioner.vocab import Vocab, detokenize

if TYPE_CHECKING:
    import onnxruntime as ort

    from server.captioner.scene import RegionClassifier

ENCODER_FILE = "encoder.onnx"
DECODER_FILE = "decoder.onnx"
VOCAB_FILE = "vocab.json"
REGIONS_FILE = "regions.json"  # optional: the scene-region classifier (server/captioner/scene.py)
DEFAULT_BEAM = 3
DEFAULT_MAX_LEN = 40
_T = TypeVar("_T")
MAX_FRAME_SIDE = 8192  # larger frames are refused rather than resized (memory)


@dataclass(frozen=True)
class Caption:
    """A sentence, its words, its total log-probability, and the time taken in milliseconds."""

    text: str
    tokens: tuple[str, ...]
    score: float
    ms: float


class Captioner:
    """Encoder + decoder sessions and their vocabulary; thread-safe ``caption``."""

    def __init__(
        self,
        encoder: ort.InferenceSession,
        decoder: ort.InferenceSession,
        vocab: Vocab,
        *,
        input_hw: tuple[int, int],
        state_size: int,
        clock: Callable[[], float] = time.perf_counter,
        regions: RegionClassifier | None = None,
    ) -> None:
        self._encoder = encoder
        self._decoder = decoder
        self.vocab = vocab
        self.input_hw = input_hw
        self.state_size = state_size
        self._clock = clock
        self.regions = regions  # grounds descriptions in the image when present
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="captioner")

    @classmethod
    def load(cls, model_dir: str | Path, *, threads: int = 1) -> Captioner:
        """Open and check ``encoder.onnx``, ``decoder.onnx`` and ``vocab.json`` in ``model_dir``.

        Runs the encoder on a black image and one decoder step to verify shapes end to end.
        ``regions.json`` (the scene-region classifier that checks captions against the image)
        is optional; without it descriptions are the captioner's sentences, marker ids grounded.

        Raises:
            CaptionerUnavailable: a file is missing or corrupt, or the models break the contract.
        """
        root = Path(model_dir)
        for name in (ENCODER_FILE, DECODER_FILE, VOCAB_FILE):
            if not (root / name).is_file():
                raise CaptionerUnavailable(f"{name} is missing from {root}")
        vocab = Vocab.load(root / VOCAB_FILE)
        try:
            import onnxruntime as ort
        except ImportError as exc:
            raise CaptionerUnavailable(
                "onnxruntime is not installed: pip install 'uav-console[captioner]'"
            ) from exc
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.log_severity_level = 3
        encoder = _session(root / ENCODER_FILE, options)
        decoder = _session(root / DECODER_FILE, options)
        input_hw = _check_encoder(encoder)
        state_size = _check_decoder(decoder)
        regions = None
        if (root / REGIONS_FILE).is_file():
            from server.captioner.scene import RegionClassifier, warm_up

            warm_up()
            try:
                regions = RegionClassifier.load(root / REGIONS_FILE)
            except (ValueError, KeyError, TypeError) as exc:
                raise CaptionerUnavailable(f"{REGIONS_FILE} is unusable: {exc}") from exc
        captioner = cls(
            encoder, decoder, vocab, input_hw=input_hw, state_size=state_size, regions=regions
        )
        captioner._smoke_test()
        return captioner

    # -- inference ----------------------------------------------------------------------------

    def preprocess(self, frame_bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
        """BGR uint8 ``[H, W, 3]`` -> the encoder's ``image`` input (see :func:`to_input`)."""
        return to_input(resize(frame_bgr, self.input_hw))

    def encode(self, frame: Any) -> npt.NDArray[np.float32]:
        """The decoder's initial state ``[1, S]`` for a frame (see :func:`as_bgr`)."""
        image = self.preprocess(as_bgr(frame))
        (state,) = self._encoder.run(["state"], {"image": image})
        return np.asarray(state, dtype=np.float32)

    def step(
        self, tokens: npt.NDArray[np.int64], state: npt.NDArray[np.float32]
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """One decoder step for a batch: token ``[B]`` + state ``[B, S]`` -> logits, state."""
        logits, new_state = self._decoder.run(
            ["logits", "state_out"], {"token": tokens, "state": state}
        )
        return logits, new_state

    def search(
        self,
        state0: npt.NDArray[np.float32],
        *,
        beam: int = DEFAULT_BEAM,
        max_len: int = DEFAULT_MAX_LEN,
    ) -> Hypothesis:
        """Greedy search for ``beam == 1``, beam search otherwise."""
        v = self.vocab
        if beam == 1:
            return greedy(self.step, state0, bos=v.bos, eos=v.eos, max_len=max_len)
        return beam_search(self.step, state0, bos=v.bos, eos=v.eos, max_len=max_len, beam=beam)

    def caption(
        self, frame: Any, *, beam: int = DEFAULT_BEAM, max_len: int = DEFAULT_MAX_LEN
    ) -> Caption:
        """Describe one frame (BGR array or JPEG/PNG bytes) in a sentence.

        Raises:
            BadFrame: the frame is not a usable image.
            ValueError: ``beam`` or ``max_len`` below 1.
        """
        if beam < 1 or max_len < 1:
            raise ValueError(f"beam and max_len must be >= 1 (got beam={beam}, max_len={max_len})")
        start = self._clock()
        hyp = self.search(self.encode(frame), beam=beam, max_len=max_len)
        words = self.vocab.words(hyp.ids)
        ms = (self._clock() - start) * 1000.0
        return Caption(detokenize(words), tuple(words), hyp.logprob, ms)

    async def describe(
        self, frame: Any, *, beam: int = DEFAULT_BEAM, max_len: int = DEFAULT_MAX_LEN
    ) -> Caption:
        """:meth:`caption` in the captioner's worker thread (the event loop keeps running)."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(
            self._executor, lambda: self.caption(frame, beam=beam, max_len=max_len)
        )

    async def run(self, fn: Callable[[], _T]) -> _T:
        """Run ``fn`` in the captioner's worker thread (one at a time, the loop keeps running)."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._executor, fn)

    def close(self) -> None:
        """Stop the worker thread (pending calls finish first)."""
        self._executor.shutdown(wait=True)

    # -- checks -------------------------------------------------------------------------------

    def _smoke_test(self) -> None:
        h, w = self.input_hw
        try:
            state = self.encode(np.zeros((h, w, 3), np.uint8))
            if state.shape != (1, self.state_size):
                raise CaptionerUnavailable(
                    f"encoder 'state' has shape {state.shape}, "
                    f"decoder expects (1, {self.state_size})"
                )
            logits, new_state = self.step(np.array([self.vocab.bos], np.int64), state)
        except CaptionerUnavailable:
            raise
        except Exception as exc:  # onnxruntime raises its own Fail/InvalidArgument types
            raise CaptionerUnavailable(f"the models failed a test run: {exc}") from exc
        if logits.shape != (1, len(self.vocab)):
            raise CaptionerUnavailable(
                f"decoder 'logits' has {logits.shape[-1]} columns but vocab.json has "
                f"{len(self.vocab)} tokens"
            )
        if new_state.shape != state.shape:
            raise CaptionerUnavailable(
                f"decoder 'state_out' shape {new_state.shape} differs from 'state' {state.shape}"
            )


def resize(frame_bgr: npt.NDArray[np.uint8], hw: tuple[int, int]) -> npt.NDArray[np.uint8]:
    """Area-average resize to ``hw`` = (height, width); the dataset generator uses it too."""
    h, w = hw
    if frame_bgr.shape[:2] == (h, w):
        return frame_bgr
    small = cv2.resize(frame_bgr, (w, h), interpolation=cv2.INTER_AREA)
    return np.asarray(small, dtype=np.uint8)


def to_input(small_bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
    """BGR uint8 ``[h, w, 3]`` (batch ``[N, h, w, 3]`` too) -> RGB float32 ``[N, 3, h, w]`` in
    [0, 1]. Mean/std normalisation, if a model wants it, is inside the encoder graph."""
    batch = small_bgr[None] if small_bgr.ndim == 3 else small_bgr
    rgb = batch[..., ::-1].astype(np.float32) / 255.0
    return np.ascontiguousarray(rgb.transpose(0, 3, 1, 2))


def as_bgr(frame: Any) -> npt.NDArray[np.uint8]:
    """A BGR uint8 image from an ``[H, W, 3]`` array (or ``[H, W]`` grey) or encoded bytes.

    Raises:
        BadFrame: None, empty, wrong dtype/shape, or bytes that do not decode to an image.
    """
    if frame is None:
        raise BadFrame("no frame")
    if isinstance(frame, bytes | bytearray | memoryview):
        buf = np.frombuffer(bytes(frame), dtype=np.uint8)
        if buf.size == 0:
            raise BadFrame("empty image bytes")
        decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        if decoded is None:
            raise BadFrame("image bytes are not a decodable JPEG/PNG")
        frame = decoded
    if not isinstance(frame, np.ndarray):
        raise BadFrame(f"frame must be an ndarray or image bytes, not {type(frame).__name__}")
    if frame.dtype != np.uint8:
        raise BadFrame(f"frame dtype must be uint8, not {frame.dtype}")
    if frame.ndim == 2:
        frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise BadFrame(f"frame shape must be [H, W, 3], not {list(frame.shape)}")
    if min(frame.shape[:2]) < 1 or max(frame.shape[:2]) > MAX_FRAME_SIDE:
        raise BadFrame(f"frame size {frame.shape[1]}x{frame.shape[0]} is out of range")
    image: npt.NDArray[np.uint8] = frame
    return image


def _session(path: Path, options: ort.SessionOptions) -> ort.InferenceSession:
    import onnxruntime as ort

    try:
        return ort.InferenceSession(
            str(path), sess_options=options, providers=["CPUExecutionProvider"]
        )
    except Exception as exc:  # onnxruntime raises several unrelated types for bad files
        raise CaptionerUnavailable(f"{path.name} is not a loadable ONNX model: {exc}") from exc


def _io(session: ort.InferenceSession) -> tuple[dict[str, Any], dict[str, Any]]:
    return (
        {i.name: i for i in session.get_inputs()},
        {o.name: o for o in session.get_outputs()},
    )


def _check_encoder(session: ort.InferenceSession) -> tuple[int, int]:
    inputs, outputs = _io(session)
    if set(inputs) != {"image"}:
        raise CaptionerUnavailable(
            f"{ENCODER_FILE} must have one input named 'image', has {sorted(inputs)}"
        )
    if "state" not in outputs:
        raise CaptionerUnavailable(
            f"{ENCODER_FILE} must have an output named 'state', has {sorted(outputs)}"
        )
    image = inputs["image"]
    shape = list(image.shape)
    if image.type != "tensor(float)" or len(shape) != 4 or shape[1] != 3:
        raise CaptionerUnavailable(
            f"{ENCODER_FILE} input 'image' must be float32 [N, 3, H, W], is {image.type} {shape}"
        )
    h, w = shape[2], shape[3]
    if not (isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0):
        raise CaptionerUnavailable(f"{ENCODER_FILE} input 'image' needs fixed H and W, has {shape}")
    return h, w


def _check_decoder(session: ort.InferenceSession) -> int:
    inputs, outputs = _io(session)
    if set(inputs) != {"token", "state"}:
        raise CaptionerUnavailable(
            f"{DECODER_FILE} must have inputs 'token' and 'state', has {sorted(inputs)}"
        )
    if not {"logits", "state_out"} <= set(outputs):
        raise CaptionerUnavailable(
            f"{DECODER_FILE} must have outputs 'logits' and 'state_out', has {sorted(outputs)}"
        )
    if inputs["token"].type != "tensor(int64)":
        raise CaptionerUnavailable(f"{DECODER_FILE} input 'token' must be int64")
    state = inputs["state"]
    shape = list(state.shape)
    if state.type != "tensor(float)" or len(shape) != 2 or not isinstance(shape[1], int):
        raise CaptionerUnavailable(
            f"{DECODER_FILE} input 'state' must be float32 [N, S] with fixed S, is "
            f"{state.type} {shape}"
        )
    return int(shape[1])
