"""Light calibration: an ArUco plate's pose and the light from its highlight.

Imports ``geometry``, ``srde`` (the highlight detector) and ``io``.
"""

from __future__ import annotations

from .board import (
    BOARD_FORMAT,
    Board,
    BoardMarker,
    aruco_dictionary,
    render_board_image,
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
from .markers import (
    MarkerDetection,
    detect_markers,
)
from .plate_highlights import (
    find_plate_highlights,
    plate_highlight_region,
)
from .plate_pose import (
    PlatePose,
    estimate_plate_pose,
    pose_from_detections,
)

__all__ = [
    "BOARD_FORMAT",
    "Board",
    "BoardMarker",
    "aruco_dictionary",
    "render_board_image",
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
    "MarkerDetection",
    "detect_markers",
    "plate_highlight_region",
    "find_plate_highlights",
    "PlatePose",
    "estimate_plate_pose",
    "pose_from_detections",
]
