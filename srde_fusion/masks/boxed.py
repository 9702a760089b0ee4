"""Object masks held as their bounding boxes, so that memory follows the objects' sizes.

A full-image mask costs ``H * W`` bytes whatever the object's size: 12 MB at 4000x3000,
768 MB for 64 objects. :class:`BoxedMasks` keeps each object as its box and the mask
cropped to it, and is still the sequence of ``(H, W)`` bool masks a masker returns
(DESIGN §5): item ``k`` is built, as a fresh array, when it is read.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from scipy import ndimage

from .._checks import check_mask
from ..boxes import BoxMask
from ..errors import MaskError

__all__ = ["BoxMask", "BoxedMasks"]


class BoxedMasks(Sequence):
    """A sequence of object masks stored as boxes; item ``k`` is a fresh ``(H, W)`` mask.

    Parameters
    ----------
    masks : sequence of BoxMask
        One per object, all of the same image shape.
    shape : (int, int)
        ``(H, W)`` of the image.

    Examples
    --------
    >>> import numpy as np
    >>> masks = BoxedMasks.from_labels(np.array([[0, 2, 2], [0, 0, 5]]))
    >>> len(masks), masks.boxes[0].box, masks[1].astype(int).tolist()
    (2, (1, 0, 3, 1), [[0, 0, 0], [0, 0, 1]])
    """

    def __init__(self, masks: Sequence[BoxMask], shape: tuple[int, int]) -> None:
        self.boxes: tuple[BoxMask, ...] = tuple(masks)
        self.shape = (int(shape[0]), int(shape[1]))
        for k, m in enumerate(self.boxes):
            if not isinstance(m, BoxMask) or m.shape != self.shape:
                raise MaskError(f"masks[{k}]: expected a BoxMask of an image of shape "
                                f"{self.shape}, got {m!r:.80}")

    @classmethod
    def from_labels(cls, labels: np.ndarray) -> BoxedMasks:
        """One mask per distinct non-zero label of an ``(H, W)`` label image, label order.

        Only one label-sized index image is made, whatever the number of labels.
        """
        if labels.size == 0:
            return cls([], labels.shape)
        values, inverse = np.unique(labels, return_inverse=True)
        inverse = inverse.reshape(labels.shape)
        first = 1 if values.size and values[0] == 0 else 0
        if first == 0:  # no background: number the objects from 1 for find_objects
            inverse += 1
        slices = ndimage.find_objects(inverse)
        out = []
        for k, sl in enumerate(slices, start=1):
            if sl is None:
                continue
            (rows, cols) = sl
            box = (cols.start, rows.start, cols.stop, rows.stop)
            out.append(BoxMask.from_crop(box, inverse[sl] == k, labels.shape))
        return cls(out, labels.shape)

    @classmethod
    def from_masks(cls, masks: Sequence[Any], shape: tuple[int, int],
                   name: str = "masks") -> BoxedMasks:
        """Validate full ``(H, W)`` masks one by one and keep each as its box."""
        out = []
        for i, m in enumerate(masks):
            if isinstance(m, BoxMask):
                out.append(m)
                continue
            out.append(BoxMask.from_mask(check_mask(m, shape, f"{name}[{i}]")))
        return cls(out, shape)

    def __len__(self) -> int:
        return len(self.boxes)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return BoxedMasks(self.boxes[index], self.shape)
        return self.boxes[index].full()

    def __iter__(self) -> Iterator[np.ndarray]:
        return (m.full() for m in self.boxes)

    @property
    def nbytes(self) -> int:
        """Bytes held by the cropped masks."""
        return sum(m.crop.nbytes for m in self.boxes)

    def __repr__(self) -> str:
        return (f"BoxedMasks({len(self)} object(s), image {self.shape[1]}x{self.shape[0]}, "
                f"{self.nbytes} bytes)")
