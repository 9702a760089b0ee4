"""Geometry of a rectified camera array: the rig, planes, triangulation.

Owns the array frame and its conventions (DESIGN §2). Imports only the foundation
(``errors``, ``_checks``, ``_json``, ``imaging``); everything else builds on it.
"""

from __future__ import annotations

from .plane import (
    Plane,
    incidence_angle_deg,
    mirror_point,
    plane_depth,
    plane_disparity,
    plane_from_lights,
)
from .rig import (
    MAX_LIGHTS,
    RIG_FORMAT,
    Camera,
    CameraRig,
    Intrinsics,
    RigLight,
    project_points,
)
from .rotations import (
    rotation_from_vector,
    rotation_to_vector,
)
from .triangulation import (
    Triangulation,
    adjacent_pairs,
    max_shift_px,
    pairwise_virtual_lights,
    robust_triangulate,
    triangulate_rectified,
)

__all__ = [
    "Plane",
    "mirror_point",
    "plane_from_lights",
    "plane_depth",
    "plane_disparity",
    "incidence_angle_deg",
    "Intrinsics",
    "Camera",
    "CameraRig",
    "RigLight",
    "RIG_FORMAT",
    "MAX_LIGHTS",
    "project_points",
    "rotation_from_vector",
    "rotation_to_vector",
    "Triangulation",
    "triangulate_rectified",
    "robust_triangulate",
    "adjacent_pairs",
    "pairwise_virtual_lights",
    "max_shift_px",
]
