"""Boolean images held over a box: an object's mask, a search region.

A full-image boolean array costs ``H * W`` bytes whatever the size of what it marks: 12 MB
at 4000x3000. :class:`BoxMask` keeps a box and the array cropped to it, and reads like the
``(H, W)`` array it stands for where code reads one: unit-step slices give that window
(a view where it lies inside the box), ``numpy.asarray`` builds the whole array. Masks
(:mod:`srde_fusion.masks`) and the other views' search regions (:mod:`srde_fusion.srde`)
are both held this way; this module sits below both.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .errors import MaskError

__all__ = ["BoxMask", "dilated", "eroded", "eroded_crop"]


@dataclass(frozen=True, eq=False)
class BoxMask:
    """A boolean image that is False outside a box, held as the box and its crop.

    Attributes
    ----------
    box : (int, int, int, int)
        ``(u0, v0, u1, v1)``, inclusive-exclusive, pixels; a box holding every True pixel
        (:meth:`from_mask` gives the smallest).
    crop : numpy.ndarray, (v1 - v0, u1 - u0), bool
        The image inside the box (read-only when it was made for the mask).
    shape : (int, int)
        ``(H, W)`` of the full image.

    Examples
    --------
    >>> import numpy as np
    >>> mask = np.zeros((4, 6), bool)
    >>> mask[1:3, 2:4] = True
    >>> boxed = BoxMask.from_mask(mask)
    >>> boxed.box, boxed.pixel_count
    ((2, 1, 4, 3), 4)
    >>> bool((np.asarray(boxed) == mask).all()), boxed[0:2, 3:6].astype(int).tolist()
    (True, [[0, 0, 0], [1, 0, 0]])
    """

    box: tuple[int, int, int, int]
    crop: np.ndarray
    shape: tuple[int, int]

    @classmethod
    def from_mask(cls, mask: np.ndarray) -> BoxMask:
        """Crop a non-empty ``(H, W)`` bool mask to its bounding box (a copy)."""
        rows = np.flatnonzero(mask.any(axis=1))
        cols = np.flatnonzero(mask.any(axis=0))
        if rows.size == 0:
            raise MaskError("mask: expected at least one pixel inside the mask, got an empty mask")
        v0, v1, u0, u1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
        return cls.from_crop((u0, v0, u1, v1), mask[v0:v1, u0:u1].copy(), mask.shape)

    @classmethod
    def from_crop(cls, box, crop: np.ndarray, shape) -> BoxMask:
        """Wrap a bool ``crop`` lying at ``box = (u0, v0, u1, v1)`` of an ``(H, W)`` image."""
        if crop.flags.owndata:  # never freeze a caller's array
            crop.setflags(write=False)
        return cls(tuple(int(b) for b in box), crop, (int(shape[0]), int(shape[1])))

    @classmethod
    def empty(cls, shape) -> BoxMask:
        """Return an image with no True pixel, held over an empty box."""
        return cls.from_crop((0, 0, 0, 0), np.zeros((0, 0), dtype=bool), shape)

    @property
    def dtype(self) -> np.dtype:
        """``bool``, as the array's."""
        return self.crop.dtype

    @property
    def ndim(self) -> int:
        """2, as the array's."""
        return 2

    @property
    def pixel_count(self) -> int:
        """True pixels."""
        return int(np.count_nonzero(self.crop))

    def full(self) -> np.ndarray:
        """Return the ``(H, W)`` bool image (a new array)."""
        u0, v0, u1, v1 = self.box
        out = np.zeros(self.shape, dtype=bool)
        out[v0:v1, u0:u1] = self.crop
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self.full()
        return out if dtype is None else out.astype(dtype)

    def window(self, box: tuple[int, int, int, int]) -> np.ndarray:
        """Return the image over any box ``(u0, v0, u1, v1)`` of it (a new bool array)."""
        u0, v0, u1, v1 = box
        bu0, bv0, bu1, bv1 = self.box
        out = np.zeros((v1 - v0, u1 - u0), dtype=bool)
        ou0, ov0, ou1, ov1 = max(u0, bu0), max(v0, bv0), min(u1, bu1), min(v1, bv1)
        if ou1 > ou0 and ov1 > ov0:
            out[ov0 - v0:ov1 - v0, ou0 - u0:ou1 - u0] = \
                self.crop[ov0 - bv0:ov1 - bv0, ou0 - bu0:ou1 - bu0]
        return out

    def __getitem__(self, key) -> np.ndarray:
        """``image[rows, cols]`` of the full image.

        Unit-step slices inside :attr:`box` give a view of :attr:`crop`, other unit-step
        slices :meth:`window`; anything else indexes the full image.
        """
        rows, cols = key
        if isinstance(rows, slice) and isinstance(cols, slice):
            v0, v1, _ = rows.indices(self.shape[0])
            u0, u1, _ = cols.indices(self.shape[1])
            if rows.step in (None, 1) and cols.step in (None, 1) and v1 >= v0 and u1 >= u0:
                bu0, bv0, bu1, bv1 = self.box
                if bu0 <= u0 and bv0 <= v0 and u1 <= bu1 and v1 <= bv1:
                    return self.crop[v0 - bv0:v1 - bv0, u0 - bu0:u1 - bu0]
                return self.window((u0, v0, u1, v1))
        return self.full()[key]


def eroded_crop(mask: np.ndarray, kernel: np.ndarray, bbox: tuple[int, int, int, int]
                ) -> tuple[np.ndarray, tuple[int, int]]:
    """``cv2.erode`` of a bool mask, computed over the box of its pixels only.

    Only the box can hold eroded pixels, and erosion takes the outside of the image as
    set, on a crop as on the whole image: the box grown by the kernel's half-size (and
    clipped to the image) gives the same pixels as eroding the whole frame.

    Parameters
    ----------
    mask : numpy.ndarray, (H, W) bool
    kernel : numpy.ndarray, (kh, kw) uint8
        Structuring element, centred.
    bbox : (int, int, int, int)
        ``(u0, v0, u1, v1)``, inclusive-exclusive: a box holding every True pixel.

    Returns
    -------
    crop : numpy.ndarray, bool
        The eroded mask over the grown box.
    origin : (int, int)
        ``(u, v)`` of ``crop[0, 0]`` in the image.
    """
    return _grown_crop(mask, kernel, bbox, cv2.erode)


def eroded(mask: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``cv2.erode`` of a bool mask as an ``(H, W)`` array, computed over the mask's box.

    See :func:`eroded_crop`; an empty mask stays empty.
    """
    return _on_mask_box(mask, kernel, cv2.erode)


def dilated(mask: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``cv2.dilate`` of a bool mask as an ``(H, W)`` array, computed near the mask only.

    Dilation reaches at most the kernel's half-size beyond the box of the mask's
    pixels, and reads nothing from outside the image: the box grown by that much (and
    clipped to the image) gives the same pixels as dilating the whole frame, at the
    cost of the object's neighbourhood instead of the frame's (a kernel of tens of
    pixels over a 640 x 480 frame costs milliseconds). An empty mask stays empty.

    Parameters
    ----------
    mask : numpy.ndarray, (H, W) bool
    kernel : numpy.ndarray, (kh, kw) uint8
        Structuring element, centred.
    """
    return _on_mask_box(mask, kernel, cv2.dilate)


def _grown_crop(mask: np.ndarray, kernel: np.ndarray, bbox: tuple[int, int, int, int],
                morph) -> tuple[np.ndarray, tuple[int, int]]:
    """Apply ``morph`` (``cv2.erode`` or ``cv2.dilate``) over ``bbox`` grown by the reach.

    The box is grown by the kernel's half-size and clipped to the image; returns the
    crop and its origin ``(u, v)``.
    """
    reach = max(kernel.shape) // 2
    h, w = mask.shape
    u0, v0, u1, v1 = bbox
    u0, v0, u1, v1 = max(u0 - reach, 0), max(v0 - reach, 0), min(u1 + reach, w), min(v1 + reach, h)
    pixels = np.ascontiguousarray(mask[v0:v1, u0:u1]).view(np.uint8)
    return morph(pixels, kernel).view(bool), (u0, v0)


def _on_mask_box(mask: np.ndarray, kernel: np.ndarray, morph) -> np.ndarray:
    """``morph`` of the mask as an ``(H, W)`` array, computed around its box only."""
    out = np.zeros(mask.shape, dtype=bool)
    x, y, bw, bh = cv2.boundingRect(np.ascontiguousarray(mask).view(np.uint8))
    if bw == 0:
        return out
    crop, (u0, v0) = _grown_crop(mask, kernel, (x, y, x + bw, y + bh), morph)
    out[v0:v0 + crop.shape[0], u0:u0 + crop.shape[1]] = crop
    return out
