"""Exceptions of moju_core. Each message says what is wrong and how to fix it."""

from __future__ import annotations


class MeasurementError(ValueError):
    """The measurements (or an input file) cannot be used as they are."""


class Cancelled(Exception):
    """The progress callback asked the solver to stop."""


class MeasurementTooLarge(MeasurementError):
    """The measurements exceed a configured size limit (frames, points or bytes)."""


class VideoError(MeasurementError):
    """A video, an image folder or a mask cannot be used for tracking."""


class VideoTooLarge(VideoError, MeasurementTooLarge):
    """A video exceeds a configured limit (bytes, resolution, frames, duration or points)."""
