"""Exceptions of marker perception and the estimator (drone/perception).

::

    PerceptionError
    ├── FrameError (ValueError)        a camera frame that is not an HxWx3 uint8 (or HxW) image
    ├── CameraModelError (ValueError)  intrinsics/extrinsics missing or not finite
    └── EstimatorError (ValueError)    a measurement or input with NaN/Inf, a bad covariance,
                                       or a timestamp that is not finite

Measurements that are merely *implausible* (Mahalanobis-gated, too old for the history) are not
errors: the estimator counts them in ``EkfStats`` and returns ``False`` from ``update_*``.
"""

from __future__ import annotations


class PerceptionError(Exception):
    """Base of every error raised by ``drone.perception``."""


class FrameError(PerceptionError, ValueError):
    """The frame is not an image perception can read."""


class CameraModelError(PerceptionError, ValueError):
    """The camera model lacks usable intrinsics or extrinsics."""


class EstimatorError(PerceptionError, ValueError):
    """An input to the EKF is not finite or not well formed."""
