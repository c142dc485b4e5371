"""Errors of the scene-description captioner.

CaptionerError
├── CaptionerUnavailable   model files missing, corrupt or not matching the I/O contract
│                          (``reason`` says which and why; the server starts without the captioner)
└── BadFrame               the image handed to ``caption`` cannot be used (empty, wrong shape,
                           undecodable JPEG)
"""

from __future__ import annotations


class CaptionerError(Exception):
    """Base of the captioner's errors."""


class CaptionerUnavailable(CaptionerError):
    """The captioner cannot run; ``reason`` is a sentence fit to show an operator."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class BadFrame(CaptionerError, ValueError):
    """The frame is not a usable image (message says why)."""
