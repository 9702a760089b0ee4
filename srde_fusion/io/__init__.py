"""Files: disparity maps, images, masks, calibration files, scene folders.

Imports ``geometry`` (the rig) and the foundation; nothing above.
"""

from __future__ import annotations

from ._files import load_npy
from .calibration_files import (
    MiddleburyCalib,
    read_kitti_calib,
    read_middlebury_calib,
    read_opencv_stereo_yaml,
)
from .disparity import (
    DISPARITY_EXTENSIONS,
    KITTI_DISPARITY_MAX_PX,
    KITTI_DISPARITY_SCALE,
    read_disparity,
    read_kitti_disparity,
    read_pfm,
    write_disparity,
    write_kitti_disparity,
    write_pfm,
)
from .images import (
    IMAGE_EXTENSIONS,
    labels_from_masks,
    masks_from_labels,
    read_image,
    read_mask,
    write_image,
    write_mask,
)
from .point_cloud import (
    disparity_to_points,
    write_ply,
)
from .scene import (
    GT_DISPARITY_STEM,
    MASK_FILE,
    METADATA_FILE,
    RIG_FILE,
    SceneData,
    is_kitti_folder,
    kitti_frames,
    list_scenes,
    read_scene,
    write_scene,
)

__all__ = [
    "load_npy",
    "MiddleburyCalib",
    "read_middlebury_calib",
    "read_kitti_calib",
    "read_opencv_stereo_yaml",
    "KITTI_DISPARITY_SCALE",
    "KITTI_DISPARITY_MAX_PX",
    "DISPARITY_EXTENSIONS",
    "read_pfm",
    "write_pfm",
    "read_kitti_disparity",
    "write_kitti_disparity",
    "read_disparity",
    "write_disparity",
    "IMAGE_EXTENSIONS",
    "read_image",
    "write_image",
    "read_mask",
    "write_mask",
    "masks_from_labels",
    "labels_from_masks",
    "write_ply",
    "disparity_to_points",
    "RIG_FILE",
    "MASK_FILE",
    "GT_DISPARITY_STEM",
    "METADATA_FILE",
    "SceneData",
    "write_scene",
    "read_scene",
    "list_scenes",
    "is_kitti_folder",
    "kitti_frames",
]
