"""Masks you already have: a label image file, a label array, or a list of masks.

A *masker* is any callable ``masker(views, rig) -> list of (H, W) bool`` giving one mask
per reflective object in the reference view (DESIGN §5).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import FileFormatError, MaskError
from ..geometry import CameraRig
from ..io import load_npy, read_mask
from .boxed import BoxedMasks, BoxMask

__all__ = [
    "MAX_OBJECTS",
    "AUTO_SPLIT_MIN_AREA_PX",
    "Masker",
    "UserMasks",
]

Masker = Callable[[Sequence[np.ndarray], CameraRig], list]

#: Most objects a mask source may hold by default. Each object is kept as its box, but
#: every object costs an SRDE estimate and a full-image mask while it is estimated.
MAX_OBJECTS = 64

#: A binary mask split automatically ignores components smaller than this, pixels (edge
#: specks of a hand-drawn or thresholded mask, not objects).
AUTO_SPLIT_MIN_AREA_PX = 16


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    return type(value).__name__


def _labels_to_masks(labels: np.ndarray, name: str, max_objects: int = 10**9
                     ) -> list[BoxMask]:
    """Split labels into masks, also accepting float arrays holding whole numbers.

    The labels are counted before any mask is built, so a label image with thousands of
    labels is refused, not split.
    """
    if np.issubdtype(labels.dtype, np.floating):
        if not np.all(np.isfinite(labels)) or np.any(labels != np.round(labels)):
            raise MaskError(f"{name}: expected integer labels (0 = background), got non-integer "
                            f"float values")
        largest = float(np.abs(labels).max()) if labels.size else 0.0
        if largest > np.iinfo(np.int32).max:  # would not survive the cast to integers
            raise MaskError(f"{name}: expected integer labels (0 = background), got values up "
                            f"to {largest:g}")
        labels = labels.astype(np.int64)
    elif labels.dtype != bool and not np.issubdtype(labels.dtype, np.integer):
        raise MaskError(f"{name}: expected a bool or integer label image, got dtype {labels.dtype}")
    if labels.size and labels.min() < 0:
        raise MaskError(f"{name}: expected labels >= 0 (0 = background), got {labels.min()}")
    values = np.unique(labels)
    n_objects = int(np.count_nonzero(values))
    if n_objects > max_objects:
        raise MaskError(f"{name}: expected at most {max_objects} objects (max_objects), got "
                        f"{n_objects} labels")
    if labels.dtype == bool:
        labels = labels.view(np.uint8)
    return list(BoxedMasks.from_labels(labels).boxes)


def connected_components(mask: BoxMask | np.ndarray, min_area_px: int) -> list[BoxMask]:
    """Split into 8-connected components of at least ``min_area_px``, raster order.

    ``mask`` is a :class:`BoxMask` or a full ``(H, W)`` bool mask; each component is
    returned as its own box.
    """
    if isinstance(mask, np.ndarray):
        mask = BoxMask.from_crop((0, 0, mask.shape[1], mask.shape[0]), mask, mask.shape)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask.crop.astype(np.uint8),
                                                         connectivity=8)
    u0, v0 = mask.box[:2]
    out = []
    for i in range(1, n):
        if stats[i, cv2.CC_STAT_AREA] < min_area_px:
            continue
        x, y = stats[i, cv2.CC_STAT_LEFT], stats[i, cv2.CC_STAT_TOP]
        w, h = stats[i, cv2.CC_STAT_WIDTH], stats[i, cv2.CC_STAT_HEIGHT]
        out.append(BoxMask.from_crop((u0 + x, v0 + y, u0 + x + w, v0 + y + h),
                                 comp[y:y + h, x:x + w] == i, mask.shape))
    return out


def _check_rig_shape(masks: list[BoxMask], rig: CameraRig, name: str) -> None:
    expected = (rig.height, rig.width)
    for i, m in enumerate(masks):
        if m.shape != expected:
            raise MaskError(f"{name}[{i}]: expected shape {expected} (the rig's image size "
                            f"{rig.width}x{rig.height}), got {m.shape}")


class UserMasks:
    """Masks you already have: a label image file, a label array, or a list of masks.

    Parameters
    ----------
    source : path, numpy.ndarray or sequence of numpy.ndarray
        A mask file (PNG label image: 0 = background, 1..K or 255 = object; or ``.npy``),
        an ``(H, W)`` bool/integer label array, a ``(K, H, W)`` stack, or a list of
        ``(H, W)`` masks.
    split_components : bool or None
        Split each label into its 8-connected components. ``None`` (default) does so for
        a binary mask (a label image with a single label), which usually holds several
        objects under one value; components under :data:`AUTO_SPLIT_MIN_AREA_PX` are then
        ignored and :attr:`notes` says what happened. ``False`` keeps every label as one
        object.
    min_area_px : int
        When splitting, components smaller than this are dropped.
    max_objects : int
        Most objects accepted (labels, list entries or components); more is a
        ``MaskError`` raised before the masks are built.

    Attributes
    ----------
    notes : tuple of str
        What was done to the masks beyond reading them (a binary mask split into objects).

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(4, 3))
    >>> labels = np.array([[0, 1, 1, 0], [0, 0, 2, 2], [0, 0, 0, 0]])
    >>> [int(m.sum()) for m in UserMasks(labels)(None, rig)]
    [2, 2]
    """

    def __init__(self, source: Any, *, split_components: bool | None = None,
                 min_area_px: int = 1, max_objects: int = MAX_OBJECTS) -> None:
        if split_components not in (None, True, False):
            raise MaskError(f"split_components: expected True, False or None, got "
                            f"{split_components!r}")
        self.source = source
        self.split_components = split_components
        self.min_area_px = int(min_area_px)
        self.max_objects = int(max_objects)
        self._masks = self._load(source, self.max_objects)
        self.notes: tuple[str, ...] = ()
        if split_components:
            self._masks = [c for m in self._masks
                           for c in connected_components(m, self.min_area_px)]
        elif split_components is None and len(self._masks) == 1 and self._is_label_image(source):
            self._split_binary()
        if not self._masks:
            raise MaskError(f"masks: expected at least one object (a non-zero label), got none "
                            f"in {self._where(source)}")
        if len(self._masks) > self.max_objects:
            raise MaskError(f"masks: expected at most {self.max_objects} objects (max_objects), "
                            f"got {len(self._masks)} in {self._where(source)}")

    @staticmethod
    def _is_label_image(source: Any) -> bool:
        """Say whether the source is a label image, where one label may hold several objects."""
        return isinstance(source, (str, os.PathLike)) or (
            isinstance(source, np.ndarray) and source.ndim == 2)

    def _split_binary(self) -> None:
        """Split a one-label mask into its components, when it has several of some size."""
        floor = max(self.min_area_px, AUTO_SPLIT_MIN_AREA_PX)
        n_all = len(connected_components(self._masks[0], 1))
        parts = connected_components(self._masks[0], floor)
        if len(parts) < 2:
            return
        specks = n_all - len(parts)
        ignored = f", {specks} under {floor} px ignored" if specks else ""
        self.notes = (f"binary mask split into {len(parts)} objects (its 8-connected "
                      f"components{ignored}); split_components=False (--mask-as-one) keeps "
                      f"one object",)
        self._masks = parts

    @staticmethod
    def _where(source: Any) -> str:
        return repr(str(source)) if isinstance(source, (str, os.PathLike)) else _describe(source)

    @staticmethod
    def _load(source: Any, max_objects: int) -> list[BoxMask]:
        if isinstance(source, (str, os.PathLike)):
            path = Path(source)
            if not path.is_file():
                raise FileFormatError(f"mask file: expected an existing file, got {str(path)!r}")
            if path.suffix.lower() == ".npy":
                labels = load_npy(path, "mask .npy")
            else:
                labels = read_mask(path)
            if labels.ndim != 2:
                raise MaskError(f"{path}: expected an (H, W) label image, got shape {labels.shape}")
            return _labels_to_masks(labels, str(path), max_objects)
        if isinstance(source, np.ndarray):
            if source.ndim == 2:
                return _labels_to_masks(source, "masks", max_objects)
            if source.ndim == 3:
                source = list(source)
            else:
                raise MaskError(f"masks: expected (H, W) labels or a (K, H, W) stack, got "
                                f"shape {source.shape}")
        if isinstance(source, Sequence) and not isinstance(source, (str, bytes)):
            out = []
            for i, m in enumerate(source):
                if not isinstance(m, np.ndarray) or m.ndim != 2:
                    raise MaskError(f"masks[{i}]: expected an (H, W) mask, got {_describe(m)}")
                found = _labels_to_masks(m, f"masks[{i}]")
                if not found:
                    raise MaskError(f"masks[{i}]: expected at least one pixel inside the mask, "
                                    f"got an empty mask")
                # A list entry is one object, whatever label values it uses.
                out.append(found[0] if len(found) == 1 else BoxMask.from_mask(
                    np.logical_or.reduce([f.full() for f in found])))
            return out
        raise MaskError(f"masks: expected a mask file path, a label array or a list of masks, "
                        f"got {_describe(source)}")

    def __call__(self, views: Any, rig: CameraRig) -> BoxedMasks:
        """Return the masks, checked against the rig's image size (``views`` is unused).

        Returns
        -------
        BoxedMasks
            A sequence of ``(H, W)`` bool masks, one per object, each a fresh array when
            read; held as the objects' boxes.
        """
        _check_rig_shape(self._masks, rig, "masks")
        return BoxedMasks(self._masks, (rig.height, rig.width))

    def __repr__(self) -> str:
        return f"UserMasks({self._where(self.source)}, {len(self._masks)} object(s))"

    def describe(self) -> str:
        """Where the masks came from and what was done to them, for reports."""
        where = str(self.source) if isinstance(self.source, (str, os.PathLike)) else "given masks"
        return "; ".join((f"user ({where}, {len(self._masks)} object(s))", *self.notes))
