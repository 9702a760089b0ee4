"""Light calibration: an ArUco plate's pose and the light from its highlight.

Imports ``geometry``, ``srde`` (the highlight detector) and ``io``.
"""

from __future__ import annotations

from .board import (
    BOARD_FORMAT,
    Board,
    BoardMarker,
    MarkerDetection,
    PlatePose,
    aruco_dictionary,
    detect_markers,
    estimate_plate_pose,
    pose_from_detections,
    project_points,
    render_board_image,
    rotation_from_vector,
    rotation_to_vector,
    write_board,
)
from .captures import (
    calibrate_light_files,
    estimate_light,
    read_capture,
)
from .light import (
    DEFAULT_MAX_INCIDENCE_DEG,
    DEFAULT_MAX_RESIDUAL_M,
    DEFAULT_MIN_VIEWS,
    LightEstimate,
    closest_point_to_rays,
    light_from_reflections,
    reflect_highlights,
)
from .plate_highlights import (
    find_plate_highlights,
    plate_highlight_region,
)

__all__ = [
    "BOARD_FORMAT",
    "Board",
    "BoardMarker",
    "MarkerDetection",
    "PlatePose",
    "aruco_dictionary",
    "detect_markers",
    "estimate_plate_pose",
    "pose_from_detections",
    "project_points",
    "render_board_image",
    "rotation_from_vector",
    "rotation_to_vector",
    "write_board",
    "estimate_light",
    "read_capture",
    "calibrate_light_files",
    "DEFAULT_MAX_INCIDENCE_DEG",
    "DEFAULT_MAX_RESIDUAL_M",
    "DEFAULT_MIN_VIEWS",
    "LightEstimate",
    "closest_point_to_rays",
    "reflect_highlights",
    "light_from_reflections",
    "plate_highlight_region",
    "find_plate_highlights",
]
