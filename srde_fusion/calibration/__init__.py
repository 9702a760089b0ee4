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
from .light import (
    LightEstimate,
    calibrate_light_files,
    closest_point_to_rays,
    estimate_light,
    find_plate_highlights,
    highlight_normal,
    light_from_reflections,
    plate_highlight_region,
    plate_scene,
    read_capture,
    reflect_highlights,
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
    "LightEstimate",
    "closest_point_to_rays",
    "reflect_highlights",
    "light_from_reflections",
    "plate_highlight_region",
    "find_plate_highlights",
    "estimate_light",
    "read_capture",
    "calibrate_light_files",
    "highlight_normal",
    "plate_scene",
]
