"""srde_fusion: geometry-based disparity for flat glossy objects, fused into neural stereo.

The specular highlight of a single light on a planar glossy object is the image of a
*virtual light*, the light's mirror image across the plane. Triangulating it from several
views fixes the plane, and with it the disparity of every pixel on the object (SRDE).
"""

from .errors import (
    BackboneError,
    BoardError,
    DisparityError,
    FileFormatError,
    ImageError,
    LightError,
    MaskError,
    RigError,
    SRDEError,
)
from .geometry import Plane, plane_disparity
from .rig import Camera, CameraRig, Intrinsics

__version__ = "0.1.0"

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
    "CameraRig",
    "Camera",
    "Intrinsics",
    "Plane",
    "plane_disparity",
]
