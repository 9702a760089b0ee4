"""srde_fusion: geometry-based disparity for flat glossy objects, fused into neural stereo.

The specular highlight of a single light on a planar glossy object is the image of a
*virtual light*, the light's mirror image across the plane. Triangulating it from several
views fixes the plane, and with it the disparity of every pixel on the object (SRDE).
SRDE's disparity replaces a stereo network's inside each object's mask.

Modules, in the order data flows through them: :mod:`~srde_fusion.rig` (cameras and
light), :mod:`~srde_fusion.io` (files), :mod:`~srde_fusion.masks` (which pixels are
reflective objects), :mod:`~srde_fusion.highlight`, :mod:`~srde_fusion.triangulation`,
:mod:`~srde_fusion.geometry`, :mod:`~srde_fusion.srde` (SRDE itself),
:mod:`~srde_fusion.refine` (photometric plane refinement), :mod:`~srde_fusion.fusion`,
:mod:`~srde_fusion.metrics`; :mod:`~srde_fusion.board` and :mod:`~srde_fusion.light`
calibrate the light; :mod:`~srde_fusion.scenes` renders synthetic scenes with exact
ground truth. Stereo-network adapters are in :mod:`srde_fusion.adapters`.
"""

from .board import Board, BoardMarker, PlatePose, estimate_plate_pose, render_board_image
from .errors import (
    BackboneError,
    BoardError,
    DisparityError,
    FileFormatError,
    ImageError,
    LightError,
    MaskError,
    RigError,
    SceneError,
    SRDEError,
)
from .evaluation import evaluate_dataset, evaluate_scene, score_fusion
from .fusion import BorderCheck, FusionResult, HybridStereo, ObjectReport, fuse, postprocess
from .geometry import Plane, mirror_point, plane_depth, plane_disparity, plane_from_lights
from .highlight import HighlightDetection, detect_highlight
from .io import (
    KITTI_DISPARITY_SCALE,
    MiddleburyCalib,
    SceneData,
    list_scenes,
    read_disparity,
    read_image,
    read_kitti_disparity,
    read_mask,
    read_middlebury_calib,
    read_opencv_stereo_yaml,
    read_pfm,
    read_scene,
    write_disparity,
    write_image,
    write_kitti_disparity,
    write_mask,
    write_pfm,
    write_scene,
)
from .light import LightEstimate, estimate_light
from .masks import HighlightSegmenter, OnnxMasker, UserMasks
from .metrics import METRIC_KEYS, evaluate, format_markdown_table, summarize
from .refine import PlaneRefinement, refine_plane
from .rig import Camera, CameraRig, Intrinsics
from .scenes import Light, Material, PlanarObject, Rendering, Scene, random_scene, render
from .srde import SRDE, SRDEResult
from .triangulation import Triangulation, triangulate_rectified

__version__ = "0.1.0"

# torch is imported only when the batched path is asked for.
_LAZY = {"BatchedSRDE": "srde_fusion.batched"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'srde_fusion' has no attribute {name!r}")

__all__ = [
    # errors
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
    # rig and geometry
    "CameraRig",
    "Camera",
    "Intrinsics",
    "Plane",
    "mirror_point",
    "plane_from_lights",
    "plane_depth",
    "plane_disparity",
    "Triangulation",
    "triangulate_rectified",
    # SRDE
    "detect_highlight",
    "HighlightDetection",
    "SRDE",
    "SRDEResult",
    "BatchedSRDE",
    "refine_plane",
    "PlaneRefinement",
    # masks and fusion
    "UserMasks",
    "HighlightSegmenter",
    "OnnxMasker",
    "fuse",
    "postprocess",
    "HybridStereo",
    "FusionResult",
    "ObjectReport",
    "BorderCheck",
    # evaluation
    "evaluate_scene",
    "evaluate_dataset",
    "score_fusion",
    # light calibration
    "Board",
    "BoardMarker",
    "PlatePose",
    "estimate_plate_pose",
    "render_board_image",
    "estimate_light",
    "LightEstimate",
    # files
    "KITTI_DISPARITY_SCALE",
    "read_pfm",
    "write_pfm",
    "read_kitti_disparity",
    "write_kitti_disparity",
    "read_disparity",
    "write_disparity",
    "read_image",
    "write_image",
    "read_mask",
    "write_mask",
    "read_middlebury_calib",
    "MiddleburyCalib",
    "read_opencv_stereo_yaml",
    "SceneData",
    "read_scene",
    "write_scene",
    "list_scenes",
    # metrics
    "METRIC_KEYS",
    "evaluate",
    "summarize",
    "format_markdown_table",
    # synthetic scenes
    "Scene",
    "PlanarObject",
    "Material",
    "Light",
    "Rendering",
    "render",
    "random_scene",
]
