"""Image operations on batches of crops in torch, matching OpenCV's results.

Borders are extended the way OpenCV extends them (symmetric for Gaussian smoothing,
reflect-101 for Sobel and box filters), per crop, so a crop padded to a common size
filters as if it stood alone. Connected components are labelled by max propagation with
pointer jumping.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from kornia.filters import filter2d_separable

from .backends import gaussian_ksize

__all__ = [
    "label_components",
]

# Pointer jumps per labelling round (see label_components).
_POINTER_JUMPS = 2


def gaussian_kernel(sigma: float, device: torch.device) -> torch.Tensor:
    """Return the kernel OpenCV's ``GaussianBlur`` uses on float32 images, ``(1, ksize)``."""
    kernel = cv2.getGaussianKernel(gaussian_ksize(sigma), sigma, cv2.CV_32F)
    return torch.from_numpy(kernel.reshape(1, -1)).to(device)


def _max3x3(labels: torch.Tensor) -> torch.Tensor:
    """Maximum over each pixel's 3 x 3 neighbourhood of non-negative ``(B, H, W)`` labels."""
    p = F.pad(labels, (1, 1, 1, 1))  # zeros: background, never above a label
    rows = torch.maximum(torch.maximum(p[:, :-2], p[:, 1:-1]), p[:, 2:])
    return torch.maximum(torch.maximum(rows[:, :, :-2], rows[:, :, 1:-1]), rows[:, :, 2:])


def label_components(binary: torch.Tensor) -> torch.Tensor:
    """Label the 8-connected components of a batch of binary images.

    Labels spread by 3 x 3 maxima restricted to the foreground, with pointer jumping
    (a pixel takes the label of the pixel its label names), until nothing changes; each
    component ends up labelled by its largest flat pixel index plus one.

    Parameters
    ----------
    binary : torch.Tensor, (B, H, W) bool
        Foreground pixels.

    Returns
    -------
    torch.Tensor, (B, H, W) int64
        0 for background; within an image, one positive label per component.

    Examples
    --------
    >>> import torch
    >>> image = torch.tensor([[[1, 1, 0, 0], [0, 0, 0, 1], [1, 0, 1, 0]]], dtype=torch.bool)
    >>> label_components(image)[0].tolist()
    [[2, 2, 0, 0], [0, 0, 0, 11], [9, 0, 11, 0]]
    """
    b, h, w = binary.shape
    index = torch.arange(1, h * w + 1, device=binary.device).view(1, h, w)
    labels = index * binary
    while True:
        grown = _max3x3(labels) * binary
        # A label names a pixel of the same component whose own label is at least as
        # large; following it twice per round halves the rounds on blob-sized components.
        for _ in range(_POINTER_JUMPS):
            flat = grown.view(b, -1)
            grown = flat.gather(1, (flat - 1).clamp_min(0)).view(b, h, w) * binary
        if torch.equal(grown, labels):
            return labels
        labels = grown


def reflect_index(start: int, stop: int, size: int, mode: str) -> np.ndarray:
    """Fold the indices ``start..stop-1`` into ``[0, size)`` as OpenCV extends a border.

    ``"symmetric"`` is ``BORDER_REFLECT`` (``cba|abc``), ``"reflect101"`` is
    ``BORDER_REFLECT_101`` (``cb|abc``); both repeat for offsets beyond the size.
    """
    i = np.arange(start, stop)
    if size == 1:
        return np.zeros_like(i)
    if mode == "symmetric":
        i = np.mod(i, 2 * size)
        return np.where(i >= size, 2 * size - 1 - i, i)
    i = np.mod(i, 2 * size - 2)
    return np.where(i >= size, 2 * size - 2 - i, i)


def extend_borders(x: torch.Tensor, sizes: np.ndarray, pad: int, mode: str) -> torch.Tensor:
    """Extend each crop of a batch by ``pad`` pixels at its own edges.

    Parameters
    ----------
    x : torch.Tensor, (B, h, w)
        Crops padded to a common size; crop b occupies ``x[b, :sizes[b, 0], :sizes[b, 1]]``.
    sizes : numpy.ndarray, (B, 2) int
        ``(height, width)`` of each crop.
    pad : int
    mode : {"symmetric", "reflect101"}

    Returns
    -------
    torch.Tensor, (B, h + 2 pad, w + 2 pad)
        What OpenCV's border would put around each crop (beyond a crop's own size, the
        extension continues; those pixels are never read as results).
    """
    b, h, w = x.shape
    rows = np.stack([reflect_index(-pad, h + pad, int(s), mode) for s in sizes[:, 0]])
    cols = np.stack([reflect_index(-pad, w + pad, int(s), mode) for s in sizes[:, 1]])
    rows_t = torch.from_numpy(rows).to(x.device)
    cols_t = torch.from_numpy(cols).to(x.device)
    x = x.gather(1, rows_t[:, :, None].expand(b, h + 2 * pad, w))
    return x.gather(2, cols_t[:, None, :].expand(b, h + 2 * pad, w + 2 * pad))


def filter_valid(x: torch.Tensor, kernel_x: torch.Tensor, kernel_y: torch.Tensor
                  ) -> torch.Tensor:
    """Correlate ``(B, h, w)`` with a separable kernel, "valid" part only.

    On a GPU this is kornia's separable filter. torch's CPU convolutions are slow for
    thin kernels, so on the CPU the same sums are taken over shifted slices.

    Returns
    -------
    torch.Tensor, (B, h - Ky + 1, w - Kx + 1)
    """
    if x.device.type != "cpu":
        return filter2d_separable(x[:, None], kernel_x[None], kernel_y[None],
                                  padding="valid")[:, 0]
    kx, ky = kernel_x.tolist(), kernel_y.tolist()
    w_out, h_out = x.shape[2] - len(kx) + 1, x.shape[1] - len(ky) + 1
    rows = kx[0] * x[:, :, :w_out]
    for i, c in enumerate(kx[1:], start=1):
        rows = rows + c * x[:, :, i:i + w_out]
    out = ky[0] * rows[:, :h_out]
    for i, c in enumerate(ky[1:], start=1):
        out = out + c * rows[:, i:i + h_out]
    return out


def crop_to_foreground(foreground: torch.Tensor, *layers: torch.Tensor):
    """Crop a batch to the bounding box of each image's foreground (one common size).

    Components and their statistics need only the foreground's surroundings; the rest
    of a search crop would only slow the labelling down.

    Returns
    -------
    origins : numpy.ndarray, (B, 2) int
        ``(u0, v0)`` of each box in its image.
    foreground : torch.Tensor, (B, h', w') bool
        False outside each image's own box.
    *layers : torch.Tensor, (B, h', w')
        The same boxes of the other layers.
    """
    b, h, w = foreground.shape
    rows = foreground.any(dim=2).cpu().numpy()
    cols = foreground.any(dim=1).cpu().numpy()
    boxes = np.zeros((b, 4), dtype=np.int64)  # v0, v1, u0, u1; empty images keep 0:1, 0:1
    boxes[:, [1, 3]] = 1
    for i in range(b):
        if rows[i].any():
            r, c = np.flatnonzero(rows[i]), np.flatnonzero(cols[i])
            boxes[i] = (r[0], r[-1] + 1, c[0], c[-1] + 1)
    hb, wb = int((boxes[:, 1] - boxes[:, 0]).max()), int((boxes[:, 3] - boxes[:, 2]).max())
    row_index = boxes[:, :1] + np.arange(hb)                             # (B, hb)
    col_index = boxes[:, 2:3] + np.arange(wb)
    inside = torch.from_numpy((row_index < boxes[:, 1:2])[:, :, None]
                              & (col_index < boxes[:, 3:4])[:, None, :]).to(foreground.device)
    rows_t = torch.from_numpy(np.minimum(row_index, h - 1)).to(foreground.device)
    cols_t = torch.from_numpy(np.minimum(col_index, w - 1)).to(foreground.device)

    def cut(x):
        x = x.gather(1, rows_t[:, :, None].expand(b, hb, w))
        return x.gather(2, cols_t[:, None, :].expand(b, hb, wb))

    return (boxes[:, [2, 0]], cut(foreground) & inside, *(cut(x) for x in layers))


def median_of(values: torch.Tensor, where: torch.Tensor) -> torch.Tensor:
    """Return numpy's median (mean of the two middle values) of each image's selected values.

    Returns
    -------
    torch.Tensor, (B,) float64
    """
    out = []
    for x, m in zip(values, where, strict=True):
        selected = x[m]
        n = selected.numel()
        lower = selected.kthvalue((n - 1) // 2 + 1).values
        upper = selected.kthvalue(n // 2 + 1).values if n % 2 == 0 else lower
        out.append((lower + upper) / 2)
    return torch.stack(out).double()


def smooth_at(extended: torch.Tensor, points_uv: np.ndarray, kernel: torch.Tensor
               ) -> torch.Tensor:
    """Separable smoothing of one crop, computed only at some of its pixels.

    The pass across the fewer distinct lines runs as one matrix product with banded
    rows of the kernel, the other pass only at the points: for candidates along a
    baseline that is a small fraction of smoothing the whole crop.

    Parameters
    ----------
    extended : torch.Tensor, (h + K - 1, w + K - 1)
        The crop extended by ``K // 2`` pixels on every side.
    points_uv : numpy.ndarray, (n, 2) int
        Pixels ``(u, v)`` of the crop.
    kernel : torch.Tensor, (K,)
        A symmetric kernel (the same along both axes).

    Returns
    -------
    torch.Tensor, (n,)
        The smoothed crop at the points ("valid" filtering of ``extended``).
    """
    taps = kernel.numel()
    u, v = points_uv[:, 0], points_uv[:, 1]
    if np.unique(u).size < np.unique(v).size:
        extended, u, v = extended.T, v, u
    lines, which = np.unique(v, return_inverse=True)
    device = extended.device
    band = torch.zeros(lines.size, extended.shape[0], dtype=extended.dtype, device=device)
    offsets = torch.from_numpy(lines[:, None] + np.arange(taps)).to(device)
    band.scatter_(1, offsets, kernel.expand(lines.size, taps))
    passed = band @ extended                                            # (lines, w + K - 1)
    windows = torch.from_numpy(u[:, None] + np.arange(taps)).to(device)
    return passed[torch.from_numpy(which).to(device)[:, None], windows] @ kernel


def weighted_centroids(weights: torch.Tensor, uu: torch.Tensor, vv: torch.Tensor) -> torch.Tensor:
    """``(u, v)`` centroid of each non-negative ``(B, h, w)`` weight image, ``(B, 2)``."""
    total = weights.sum(dim=(1, 2)).clamp_min(float(np.finfo(np.float64).tiny))
    return torch.stack([(weights * uu).sum(dim=(1, 2)), (weights * vv).sum(dim=(1, 2))],
                       dim=1) / total[:, None]


def bbox_of(mask: torch.Tensor) -> torch.Tensor:
    """``(u0, v0, u1, v1)``, inclusive-exclusive, of each ``(B, h, w)`` mask, ``(B, 4)``."""
    b, h, w = mask.shape
    rows, cols = mask.any(dim=2), mask.any(dim=1)
    ar_v = torch.arange(h, device=mask.device)
    ar_u = torch.arange(w, device=mask.device)
    return torch.stack([torch.where(cols, ar_u, w).amin(dim=1),
                        torch.where(rows, ar_v, h).amin(dim=1),
                        torch.where(cols, ar_u, -1).amax(dim=1) + 1,
                        torch.where(rows, ar_v, -1).amax(dim=1) + 1], dim=1)
