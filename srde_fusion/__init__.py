"""srde_fusion: geometry-based disparity for flat glossy objects, fused into neural stereo.

The specular highlight of a single light on a planar glossy object is the image of a
*virtual light*, the light's mirror image across the plane. Triangulating it from several
views fixes the plane, and with it the disparity of every pixel on the object (SRDE).
SRDE's disparity replaces a stereo network's inside each object's mask.

This namespace holds the names a pipeline needs; each subpackage re-exports the rest of
its concern. In the order data flows through them:

- :mod:`~srde_fusion.geometry` -- the rig, planes, triangulation of the virtual light;
- :mod:`~srde_fusion.io` -- disparity maps, images, masks, calibration files, scene folders;
- :mod:`~srde_fusion.masks` -- which pixels are reflective objects;
- :mod:`~srde_fusion.srde` -- highlight detection, SRDE, the photometric refinement;
- :mod:`~srde_fusion.fusion` -- SRDE inside the objects, the backbone elsewhere;
- :mod:`~srde_fusion.evaluation` -- metrics, scene and dataset scores, figures;
- :mod:`~srde_fusion.calibration` -- the light's position from an ArUco plate;
- :mod:`~srde_fusion.synthetic` -- rendered scenes with exact ground truth;
- :mod:`~srde_fusion.cli` -- the ``srde-fusion`` command.

Stereo-network adapters are in :mod:`srde_fusion.adapters`.
"""

from __future__ import annotations

import logging

from .calibration import Board, LightEstimate, estimate_light
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
from .evaluation import evaluate, evaluate_dataset, evaluate_scene
from .fusion import FusionResult, HybridStereo, fuse, postprocess
from .geometry import CameraRig, Plane, RigLight
from .io import read_disparity, read_image, read_mask, read_scene, write_disparity
from .masks import HighlightSegmenter, OnnxMasker, UserMasks
from .srde import SRDE, BatchedSRDE, SRDEResult, detect_highlight

__version__ = "0.1.0"

# The library logs to "srde_fusion" and leaves handlers to the application (the CLI's -v).
logging.getLogger(__name__).addHandler(logging.NullHandler())



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
    # the rig and SRDE
    "CameraRig",
    "RigLight",
    "Plane",
    "SRDE",
    "SRDEResult",
    "BatchedSRDE",
    "detect_highlight",
    # masks and fusion
    "UserMasks",
    "HighlightSegmenter",
    "OnnxMasker",
    "fuse",
    "postprocess",
    "HybridStereo",
    "FusionResult",
    # files
    "read_image",
    "read_mask",
    "read_disparity",
    "write_disparity",
    "read_scene",
    # evaluation
    "evaluate",
    "evaluate_scene",
    "evaluate_dataset",
    # light calibration
    "Board",
    "estimate_light",
    "LightEstimate",
]
