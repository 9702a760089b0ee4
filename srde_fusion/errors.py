"""Error types raised by srde_fusion for invalid input.

Every error a caller can provoke is an :class:`SRDEError`, which is also a
:class:`ValueError`, so ``except ValueError`` keeps working for code that does not
know this library. Geometric failures (no highlight, degenerate plane) are *not*
errors: they are results with a ``status`` and a ``reason``.
"""

from __future__ import annotations

__all__ = [
    "SRDEError",
    "RigError",
    "ImageError",
    "MaskError",
    "DisparityError",
    "FileFormatError",
    "LightError",
    "BackboneError",
    "BoardError",
    "SceneError",
]


class SRDEError(ValueError):
    """Base class of every input error raised by srde_fusion."""


class RigError(SRDEError):
    """A camera rig (or its ``rig.json``) is invalid."""


class ImageError(SRDEError):
    """Views have the wrong count, shape, dtype or values."""


class MaskError(SRDEError):
    """An object mask is empty, has the wrong shape or cannot be interpreted."""


class DisparityError(SRDEError):
    """A disparity map has the wrong shape or dtype."""


class FileFormatError(SRDEError):
    """A file is missing, truncated or not in the expected format."""


class LightError(SRDEError):
    """The light position is missing or invalid, or light calibration cannot proceed."""


class BackboneError(SRDEError):
    """A stereo model cannot be loaded or its inputs/outputs do not fit its spec."""


class BoardError(SRDEError):
    """A calibration board description is invalid."""


class SceneError(SRDEError):
    """A synthetic scene description (object, material, background, option) is invalid."""
