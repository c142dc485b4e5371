"""Frame decoding and preprocessing (no model needed): any input is an image or BadFrame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.captioner.errors import BadFrame
from server.captioner.model import as_bgr, resize, to_input


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_decode_or_raise_bad_frame(data: bytes) -> None:
    try:
        img = as_bgr(data)
    except BadFrame as exc:
        assert str(exc)
    else:
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3


def test_jpeg_round_trip_and_preprocessing() -> None:
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 256, (360, 640, 3), dtype=np.uint8)
    frame[:, :320] = (255, 0, 0)  # left half pure blue in BGR
    ok, buf = cv2.imencode(".png", frame)
    assert ok and np.array_equal(as_bgr(buf.tobytes()), frame)
    x = to_input(resize(frame, (96, 160)))
    assert x.shape == (1, 3, 96, 160) and x.dtype == np.float32
    assert x.min() >= 0.0 and x.max() <= 1.0
    # RGB order: the blue half is channel 2 = 1.0, channel 0 = 0.0
    assert x[0, 2, :, :70].min() == pytest.approx(1.0) and x[0, 0, :, :70].max() == 0.0


def test_batch_preprocessing_matches_single() -> None:
    imgs = np.random.default_rng(1).integers(0, 256, (3, 96, 160, 3), dtype=np.uint8)
    assert np.array_equal(to_input(imgs)[1:2], to_input(imgs[1]))
