"""Point clouds in PLY files, as Open3D, MeshLab and CloudCompare read them."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import FileFormatError
from ..geometry import CameraRig
from ._files import write_bytes

__all__ = ["write_ply", "disparity_to_points"]


def disparity_to_points(disparity_px: np.ndarray, rig: CameraRig,
                        image: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """3D points of every valid disparity pixel of the reference view, and their colours.

    Parameters
    ----------
    disparity_px : numpy.ndarray, (H, W) float
        Stereo-pair disparity, pixels; NaN, inf and values <= 0 have no point.
    rig : CameraRig
    image : numpy.ndarray, (H, W, 3) or (H, W) uint8, optional
        The reference view, for the colours (grey when absent).

    Returns
    -------
    points_m : numpy.ndarray, (N, 3) float32
        Array frame, metres, in raster order.
    colors : numpy.ndarray, (N, 3) uint8
        RGB of each point.
    """
    depth = rig.disparity_to_depth(disparity_px)
    valid = np.isfinite(depth)
    vv, uu = np.nonzero(valid)
    points = rig.backproject(np.stack([uu, vv], axis=1).astype(np.float64), depth[valid])
    if image is None:
        colors = np.full((uu.size, 3), 128, np.uint8)
    else:
        pixels = image[vv, uu]
        colors = np.repeat(pixels[:, None], 3, axis=1) if pixels.ndim == 1 else pixels[:, :3]
    return points.astype(np.float32), np.ascontiguousarray(colors, dtype=np.uint8)


def write_ply(path: str | os.PathLike, points_m: np.ndarray, colors: np.ndarray | None = None
              ) -> Path:
    """Write points (and RGB colours) as a binary little-endian PLY file.

    Parameters
    ----------
    path : path
    points_m : numpy.ndarray, (N, 3) float
        Coordinates, metres.
    colors : numpy.ndarray, (N, 3) uint8, optional

    Returns
    -------
    pathlib.Path

    Raises
    ------
    FileFormatError
        Points or colours of the wrong shape, or a file that cannot be written.
    """
    p = Path(path)
    points = np.asarray(points_m)
    if points.ndim != 2 or points.shape[1] != 3:
        raise FileFormatError(f"{p}: expected points of shape (N, 3), got {points.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}",
              "property float x", "property float y", "property float z"]
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (len(points), 3) or colors.dtype != np.uint8:
            raise FileFormatError(f"{p}: expected uint8 colours of shape ({len(points)}, 3), got "
                                  f"{colors.dtype} {colors.shape}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    rows = np.empty(len(points), dtype=fields)
    rows["x"], rows["y"], rows["z"] = points[:, 0], points[:, 1], points[:, 2]
    if colors is not None:
        rows["red"], rows["green"], rows["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    text = "\n".join([*header, "end_header"]) + "\n"
    write_bytes(p, text.encode("ascii") + rows.tobytes())
    return p
