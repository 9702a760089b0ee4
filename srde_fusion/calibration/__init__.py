"""Light calibration: an ArUco plate's pose and the light from its highlight.

Imports ``geometry``, ``srde`` (the highlight detector), ``io`` and, for its figures,
``evaluation``'s figure writer.
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
    MAX_IMAGE_READ_LIGHTS,
    LightCalibration,
    LightsEstimate,
    calibrate_light_files,
    estimate_light,
    estimate_lights,
    read_capture,
)
from .correspondence import (
    CONTRADICTED_SET_PX,
    DEFAULT_MATCH_TOLERANCE_PX,
    CaptureMatch,
    HighlightGrouping,
    HighlightSet,
    group_highlights,
    leave_out_contradicted_sets,
    match_captures,
)
from .figures import (
    capture_figure,
    highlight_residuals_px,
    light_figure,
    write_calibration_figures,
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
from .photometric import (
    PhotometricLight,
    photometric_light,
    photometric_lights,
    with_photometric,
)
from .plate_highlights import (
    find_plate_highlight_candidates,
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
    "estimate_lights",
    "PhotometricLight",
    "photometric_light",
    "photometric_lights",
    "with_photometric",
    "LightsEstimate",
    "LightCalibration",
    "MAX_IMAGE_READ_LIGHTS",
    "DEFAULT_MATCH_TOLERANCE_PX",
    "HighlightSet",
    "HighlightGrouping",
    "CaptureMatch",
    "group_highlights",
    "match_captures",
    "leave_out_contradicted_sets",
    "CONTRADICTED_SET_PX",
    "find_plate_highlight_candidates",
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
    "capture_figure",
    "light_figure",
    "write_calibration_figures",
    "highlight_residuals_px",
]
