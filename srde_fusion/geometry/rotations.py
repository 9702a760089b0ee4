"""Rotations as matrices and as Rodrigues vectors (OpenCV's axis-angle convention).

A rotation vector's direction is the axis and its length the angle in radians;
``dst_from_src`` matrices act on column vectors, ``x_dst = R @ x_src``.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

__all__ = ["rotation_from_vector", "rotation_to_vector"]


def rotation_from_vector(rvec: Any) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` of a Rodrigues vector ``(3,)``."""
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]


def rotation_to_vector(rotation: np.ndarray) -> np.ndarray:
    """Rodrigues vector ``(3,)`` of a rotation matrix ``(3, 3)``."""
    return cv2.Rodrigues(np.asarray(rotation, dtype=np.float64))[0].ravel()
