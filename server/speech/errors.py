"""Errors of offline speech recognition.

Tree::

    SpeechError                  anything speech cannot do; the message says what and why
    ├── ModelError               the ASR model cannot be used
    │   ├── ModelMissing         no model directory / no model.bin / faster-whisper absent
    │   └── ModelChecksumError   model.bin is not the file its SHA-256 says it should be
    ├── AudioError               the audio cannot be recognised (HTTP 4xx, a JSON "error" line)
    │   ├── NotWav               not a RIFF/WAVE file, or a WAV that is not 16-bit PCM
    │   ├── EmptyAudio           zero samples
    │   └── AudioTooLong         over the limit (30 s for one request)
    ├── Busy                     every decoder is busy and the queue is full (HTTP 503)
    └── SynthesisError           a reply cannot be spoken (no voice, the voice failed)
"""

from __future__ import annotations


class SpeechError(Exception):
    """Base of every speech error."""


class ModelError(SpeechError):
    """The ASR model cannot be used."""


class ModelMissing(ModelError):
    """The model directory, its model.bin or the faster-whisper package is missing."""


class ModelChecksumError(ModelError):
    """model.bin does not have the SHA-256 it must have (a damaged or substituted file)."""


class AudioError(SpeechError):
    """The audio cannot be recognised."""


class NotWav(AudioError):
    """Not a 16-bit PCM WAV file."""


class EmptyAudio(AudioError):
    """No samples at all."""


class AudioTooLong(AudioError):
    """More audio than one request may carry."""


class Busy(SpeechError):
    """Every decoder is busy and the waiting line is full; try again shortly."""


class SynthesisError(SpeechError):
    """A reply cannot be spoken: no voice is installed, or the voice failed on this text."""
