"""SRDE with its pixel work in torch, batched over the views (kornia filters).

:class:`BatchedSRDE` is :class:`~srde_fusion.srde.SRDE` with every step that touches
pixels done by torch on a device: luminance (sRGB decoding through a table), the
brightness search along each baseline (Gaussian smoothing), and highlight detection
(thresholds, medians, 8-connected components, centroids; the paper detector's Sobel
gradient and box statistics). The reference view is processed first; all other views
of a frame then go through in one batch. Views given as tensors are read where they
are, so on a GPU the images never leave it. What needs only a few numbers per view
stays in numpy on the host: candidate positions along the baselines, the search discs
(small boolean crops, uploaded), the triangulation, the plane and the disparity map.
The photometric refinement, when enabled, runs on host copies of the views.

Results agree with :class:`~srde_fusion.srde.SRDE`: each crop is extended at its own
edges the way OpenCV extends it (symmetric for the Gaussian smoothing, reflect-101 for
the Sobel and box filters), so the two differ only in the order of floating-point sums.
That can flip a comparison that sits exactly on a threshold, nothing more.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from kornia.filters import filter2d, filter2d_separable, get_spatial_gradient_kernel2d

from ._checks import check_views
from .errors import ImageError, SRDEError
from .highlight import (
    _BLOB_LEVEL,
    _BLOB_MARGIN_PX,
    _MIN_CORE_PX,
    _PEAK_SMOOTHING_SIGMA_PX,
    _WHITE_FLOOR,
    _WHITE_SIGMA_PX,
    HighlightDetection,
    _lobe_center,
)
from .imaging import _SRGB_LUT, REC709_LUMA, SATURATION_LEVEL_U8
from .srde import _MIN_BLOB_AREA_PX, SRDE, SRDEResult

__all__ = ["BatchedSRDE", "label_components"]



def _gaussian_ksize(sigma: float) -> int:
    """OpenCV's Gaussian kernel size for float images: ``round(8 sigma + 1)``, made odd."""
    return int(round(sigma * 8 + 1)) | 1


def _gaussian_kernel(sigma: float, device: torch.device) -> torch.Tensor:
    """Return the kernel OpenCV's ``GaussianBlur`` uses on float32 images, ``(1, ksize)``."""
    kernel = cv2.getGaussianKernel(_gaussian_ksize(sigma), sigma, cv2.CV_32F)
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
        flat = grown.view(b, -1)
        # A label names a pixel of the same component whose own label is at least as large.
        grown = flat.gather(1, (flat - 1).clamp_min(0)).view(b, h, w) * binary
        if torch.equal(grown, labels):
            return labels
        labels = grown


def _reflect_index(start: int, stop: int, size: int, mode: str) -> np.ndarray:
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


def _extend(x: torch.Tensor, sizes: np.ndarray, pad: int, mode: str) -> torch.Tensor:
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
    rows = np.stack([_reflect_index(-pad, h + pad, int(s), mode) for s in sizes[:, 0]])
    cols = np.stack([_reflect_index(-pad, w + pad, int(s), mode) for s in sizes[:, 1]])
    rows_t = torch.from_numpy(rows).to(x.device)
    cols_t = torch.from_numpy(cols).to(x.device)
    x = x.gather(1, rows_t[:, :, None].expand(b, h + 2 * pad, w))
    return x.gather(2, cols_t[:, None, :].expand(b, h + 2 * pad, w + 2 * pad))


def _smooth_at(extended: torch.Tensor, points_uv: np.ndarray, kernel: torch.Tensor
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


@dataclass(frozen=True)
class _Crops:
    """Crops of several views, padded to one size: ``pixels (B, h, w[, 3])`` as stored."""

    pixels: torch.Tensor
    views: tuple[int, ...]
    origins: np.ndarray   # (B, 2) int: (u0, v0) of each crop in its view
    sizes: np.ndarray     # (B, 2) int: (height, width) of each crop


class _DeviceViews(Sequence):
    """The views of one frame on the device, with host copies made only when asked for.

    Indexing gives host numpy images (what the photometric refinement reads);
    ``tensors`` holds the device images.
    """

    def __init__(self, tensors: list[torch.Tensor], host: list[np.ndarray] | None) -> None:
        self.tensors = tensors
        self._host = host if host is not None else [None] * len(tensors)

    def __len__(self) -> int:
        return len(self.tensors)

    def __getitem__(self, j):
        if isinstance(j, slice):
            return [self[i] for i in range(*j.indices(len(self)))]
        if self._host[j] is None:
            self._host[j] = self.tensors[j].cpu().numpy()
        return self._host[j]


class _Engine:
    """The device half of :class:`BatchedSRDE`: luminance, smoothing, detection."""

    def __init__(self, srde: BatchedSRDE, device: torch.device) -> None:
        self.srde = srde
        self.device = device
        self.encoding = srde.rig.image_encoding
        self.lut = torch.from_numpy(_SRGB_LUT).to(device)
        self.luma = torch.from_numpy(REC709_LUMA).to(device)
        self.blob_kernel = _gaussian_kernel(_PEAK_SMOOTHING_SIGMA_PX, device)
        self.white_kernel = _gaussian_kernel(_WHITE_SIGMA_PX, device)
        self.whites = None
        if srde.white_references is not None:
            self.whites = [torch.from_numpy(np.ascontiguousarray(r)).to(device)
                           for r in srde.white_references]

    # ------------------------------------------------------------------ pixels
    def crops(self, images: Sequence[torch.Tensor], views, boxes) -> _Crops:
        """Cut ``(u0, v0, u1, v1)`` boxes out of views, padded to the largest box."""
        boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 4)
        sizes = np.stack([boxes[:, 3] - boxes[:, 1], boxes[:, 2] - boxes[:, 0]], axis=1)
        hm, wm = (int(s) for s in sizes.max(axis=0))
        out = []
        for j, (u0, v0, _, _), (h, w) in zip(views, boxes, sizes, strict=True):
            # Beyond its own size a crop repeats itself; those pixels are never results.
            rows = torch.from_numpy(v0 + _reflect_index(0, hm, int(h), "symmetric"))
            cols = torch.from_numpy(u0 + _reflect_index(0, wm, int(w), "symmetric"))
            image = images[j]
            out.append(image.index_select(0, rows.to(image.device))
                       .index_select(1, cols.to(image.device)))
        pixels = torch.stack(out).to(self.device)
        return _Crops(pixels, tuple(views), boxes[:, :2], sizes)

    def luminance(self, pixels: torch.Tensor) -> torch.Tensor:
        """Linear luminance, ``(B, h, w)`` float32 (as :func:`~srde_fusion.imaging.luminance`)."""
        if self.encoding == "srgb":
            if pixels.dtype == torch.uint8:
                lin = self.lut[pixels.long()]
            else:
                x = pixels.float()
                lin = torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
        else:
            lin = pixels.float() / 255.0 if pixels.dtype == torch.uint8 else pixels.float()
        return lin @ self.luma if lin.dim() == 4 else lin

    def saturated(self, pixels: torch.Tensor) -> torch.Tensor:
        """Clipped pixels, ``(B, h, w)`` bool (as :func:`~srde_fusion.imaging.saturation_mask`)."""
        level = SATURATION_LEVEL_U8 if pixels.dtype == torch.uint8 else SATURATION_LEVEL_U8 / 255.0
        sat = pixels >= level
        return sat.any(dim=-1) if sat.dim() == 4 else sat

    def normalized_luminance(self, images, crops: _Crops) -> torch.Tensor:
        """Crop luminance, divided by the smoothed white reference when there is one."""
        lum = self.luminance(crops.pixels)
        if self.whites is None:
            return lum
        boxes = np.concatenate([crops.origins, crops.origins + crops.sizes[:, ::-1]], axis=1)
        white = self.luminance(self.crops(self.whites, crops.views, boxes).pixels)
        pad = self.white_kernel.shape[1] // 2
        white = _extend(white, crops.sizes, pad, "symmetric")[:, None]
        white = filter2d_separable(white, self.white_kernel, self.white_kernel,
                                   padding="valid")[:, 0]
        return lum / white.clamp_min(_WHITE_FLOOR)

    def smooth(self, lum: torch.Tensor, sizes: np.ndarray, kernel: torch.Tensor) -> torch.Tensor:
        """Gaussian smoothing of each crop with OpenCV's symmetric border, ``(B, h, w)``."""
        x = _extend(lum, sizes, kernel.shape[1] // 2, "symmetric")[:, None]
        return filter2d_separable(x, kernel, kernel, padding="valid")[:, 0]

    # ------------------------------------------------------------------ search
    def brightest(self, images, candidates) -> list[int]:
        """Index of the brightest candidate of each view (see ``SRDE._search_region``).

        Parameters
        ----------
        images : sequence of torch.Tensor
        candidates : list of (int, _Candidates)
            One entry per view; all share the reference blob, hence the smoothing.
        """
        views = [j for j, _ in candidates]
        boxes = [(*c.lo, *c.hi) for _, c in candidates]
        crops = self.crops(images, views, boxes)
        kernel = _gaussian_kernel(candidates[0][1].sigma_px, self.device)
        extended = _extend(self.luminance(crops.pixels), crops.sizes, kernel.shape[1] // 2,
                           "symmetric")
        best = []
        for ext, (_, c) in zip(extended, candidates, strict=True):
            brightness = torch.full((c.w_v.size,), -math.inf, dtype=torch.float64,
                                    device=self.device)
            local = c.pix[c.ok] - np.asarray(c.lo)
            values = _smooth_at(ext, local, kernel[0])
            brightness[torch.from_numpy(np.flatnonzero(c.ok)).to(self.device)] = values.double()
            best.append(brightness)
        # argmax returns the first of equal maxima, as numpy's does.
        return [int(i) for i in torch.stack([b.argmax() for b in best]).tolist()]

    # ------------------------------------------------------------------ detection
    def detect(self, images, items) -> list[HighlightDetection]:
        """Detect the highlight in several views at once.

        Parameters
        ----------
        images : sequence of torch.Tensor
        items : list of (int, numpy.ndarray, float or None)
            ``(view, region (H, W) bool, level)``; each region non-empty.
        """
        srde = self.srde
        paper = srde.detector == "paper"
        margin = srde.window // 2 + 2 if paper else _BLOB_MARGIN_PX
        boxes = []
        for _, region, _ in items:
            h, w = region.shape
            rows = np.flatnonzero(region.any(axis=1))
            cols = np.flatnonzero(region.any(axis=0))
            boxes.append((max(int(cols[0]) - margin, 0), max(int(rows[0]) - margin, 0),
                          min(int(cols[-1]) + 1 + margin, w), min(int(rows[-1]) + 1 + margin, h)))
        crops = self.crops(images, [j for j, _, _ in items], boxes)
        b, hm, wm = crops.pixels.shape[:3]
        region_np = np.zeros((b, hm, wm), dtype=bool)
        for i, ((_, region, _), (u0, v0, u1, v1)) in enumerate(zip(items, boxes, strict=True)):
            region_np[i, :v1 - v0, :u1 - u0] = region[v0:v1, u0:u1]
        region_t = torch.from_numpy(region_np).to(self.device)
        lum = self.normalized_luminance(images, crops)
        if paper:
            found = self._paper(lum, region_t, crops.sizes)
        else:
            levels = [level for _, _, level in items]
            found = self._blob(lum, region_t, crops, levels, region_np)
        out = []
        for det, (u0, v0) in zip(found, crops.origins, strict=True):
            if det.found:
                bu0, bv0, bu1, bv1 = det.bbox
                u0, v0 = int(u0), int(v0)
                det = HighlightDetection(True, det.center_uv + np.array([u0, v0], np.float64),
                                         det.area_px, (bu0 + u0, bv0 + v0, bu1 + u0, bv1 + v0),
                                         det.score, "", det.level)
            out.append(det)
        return out

    def _blob(self, lum, region, crops: _Crops, levels, region_np) -> list[HighlightDetection]:
        """Run the blob detector (``highlight._detect_blob``) on a batch of crops."""
        srde = self.srde
        b, h, w = lum.shape
        dev = self.device
        smooth = self.smooth(lum, crops.sizes, self.blob_kernel)
        count = region.flatten(1).sum(dim=1)
        ordered = torch.where(region, lum, torch.nan).flatten(1).sort(dim=1).values
        lower = ordered.gather(1, ((count - 1) // 2)[:, None])[:, 0]
        upper = ordered.gather(1, (count // 2)[:, None])[:, 0]
        background = ((lower + upper) / 2).double()                    # numpy's median
        peak = torch.where(region, smooth, -torch.inf).flatten(1).amax(dim=1).double()
        contrast = peak - background
        given = torch.tensor([math.nan if lv is None else lv for lv in levels],
                             dtype=torch.float64, device=dev)
        level = torch.where(torch.isnan(given), background + _BLOB_LEVEL * contrast, given)
        excess = torch.where(region, lum - level.float()[:, None, None], 0.0)
        foreground = excess > 0
        labels = label_components(foreground).flatten(1)                # (B, h w)
        bins = h * w + 1
        light = torch.zeros(b, bins, dtype=torch.float64, device=dev)
        light.scatter_add_(1, labels, excess.clamp_min(0).flatten(1).double())
        light[:, 0] = -1.0
        best = light.argmax(dim=1)
        blob = (labels == best[:, None]).view(b, h, w) & foreground
        area = blob.flatten(1).sum(dim=1)
        vv = torch.arange(h, device=dev, dtype=torch.float64).view(1, h, 1)
        uu = torch.arange(w, device=dev, dtype=torch.float64).view(1, 1, w)
        weights = torch.where(blob, excess.double(), 0.0)
        total = weights.sum(dim=(1, 2))
        center = torch.stack([(weights * uu).sum(dim=(1, 2)), (weights * vv).sum(dim=(1, 2))],
                             dim=1) / total[:, None]
        if srde.blob_center == "core":
            core = blob & self.saturated(crops.pixels)
            n_core = core.flatten(1).sum(dim=1)
            core_center = torch.stack([(core * uu).sum(dim=(1, 2)), (core * vv).sum(dim=(1, 2))],
                                      dim=1) / n_core.clamp_min(1)[:, None]
            center = torch.where((n_core >= _MIN_CORE_PX)[:, None], core_center, center)
        rows_any, cols_any = blob.any(dim=2), blob.any(dim=1)
        big = torch.tensor(max(h, w), device=dev)
        ar_v, ar_u = torch.arange(h, device=dev), torch.arange(w, device=dev)
        bbox = torch.stack([torch.where(cols_any, ar_u, big).amin(dim=1),
                            torch.where(rows_any, ar_v, big).amin(dim=1),
                            torch.where(cols_any, ar_u, -1).amax(dim=1) + 1,
                            torch.where(rows_any, ar_v, -1).amax(dim=1) + 1], dim=1)
        stats = {name: t.cpu().numpy() for name, t in dict(
            background=background, peak=peak, contrast=contrast, level=level,
            any=foreground.flatten(1).any(dim=1), area=area, center=center, bbox=bbox).items()}
        out = []
        for i in range(b):
            bg, pk, ct, lv = (float(stats[k][i]) for k in ("background", "peak", "contrast",
                                                            "level"))
            if ct < srde.min_contrast:
                out.append(HighlightDetection.missing(
                    f"no bright blob: peak {pk:.4f} is only {ct:.4f} above the region's median "
                    f"{bg:.4f} (min_contrast {srde.min_contrast:g}, linear intensity)"))
                continue
            if not stats["any"][i]:
                out.append(HighlightDetection.missing(
                    f"no pixel above the level {lv:.4f} in the search region"))
                continue
            area_i = int(stats["area"][i])
            if area_i < _MIN_BLOB_AREA_PX:
                out.append(HighlightDetection.missing(
                    f"brightest blob has {area_i} px above the level {lv:.4f}, fewer than "
                    f"min_area_px {_MIN_BLOB_AREA_PX}"))
                continue
            center_uv = stats["center"][i].astype(np.float64)
            if srde.blob_center == "lobe":
                center_uv = self._lobe(lum[i], crops.pixels[i], region_np[i],
                                       blob[i].cpu().numpy(), bg, ct, center_uv)
            out.append(HighlightDetection(True, center_uv, area_i,
                                          tuple(int(x) for x in stats["bbox"][i]), ct, "", lv))
        return out

    def _lobe(self, lum, pixels, region, blob, background, contrast, fallback) -> np.ndarray:
        """Fit the lobe centre on the host, from this crop (a least-squares fit)."""
        fitted = _lobe_center(lum.cpu().numpy(), self.saturated(pixels[None])[0].cpu().numpy(),
                              region, blob, background, contrast)
        return fallback if fitted is None else fitted

    def _paper(self, lum, region, sizes: np.ndarray) -> list[HighlightDetection]:
        """Run the paper's gradient detector (``highlight._detect_paper``) on a batch of crops."""
        srde = self.srde
        b, h, w = lum.shape
        dev = self.device
        half = srde.window // 2
        # Sobel then box statistics, both with reflect-101 borders: |gradient| of the
        # extended crop is the extension of the crop's |gradient|, so one extension does.
        x = _extend(lum, sizes, half + 1, "reflect101")[:, None]
        sobel = get_spatial_gradient_kernel2d("sobel", 1).to(dev, torch.float32)
        gx = filter2d(x, sobel[0][None], padding="valid")
        gy = filter2d(x, sobel[1][None], padding="valid")
        grad = torch.sqrt(gx * gx + gy * gy)                           # (B, 1, h + 2 half, ...)
        box = torch.full((1, srde.window), 1.0 / srde.window, device=dev)
        mean = filter2d_separable(grad, box, box, padding="valid")[:, 0]
        mean_sq = filter2d_separable(grad * grad, box, box, padding="valid")[:, 0]
        grad = grad[:, 0, half:half + h, half:half + w]
        std = torch.sqrt(torch.clamp(mean_sq - mean * mean, min=0.0))
        threshold = mean + srde.k * std
        candidates = region & (grad > threshold)
        labels = label_components(candidates).flatten(1)
        bins = h * w + 1
        flat_v = torch.arange(h, device=dev).repeat_interleave(w).expand(b, -1)
        flat_u = torch.arange(w, device=dev).repeat(h).expand(b, -1)

        def reduce(values, how, fill):
            out = torch.full((b, bins), fill, dtype=values.dtype, device=dev)
            return out.scatter_reduce_(1, labels, values, reduce=how, include_self=False)

        area = torch.zeros(b, bins, dtype=torch.int64, device=dev)
        area.scatter_add_(1, labels, torch.ones_like(labels))
        u_min, u_max = reduce(flat_u, "amin", w), reduce(flat_u, "amax", -1)
        v_min, v_max = reduce(flat_v, "amin", h), reduce(flat_v, "amax", -1)
        widths, heights = u_max - u_min + 1, v_max - v_min + 1
        area[:, 0] = 0
        keep = (widths >= srde.min_extent_px) & (heights >= srde.min_extent_px) & (area > 0)
        best = torch.where(keep, area, -1).argmax(dim=1)
        largest = area.argmax(dim=1)
        ring = (labels == best[:, None]).view(b, h, w) & candidates
        n_ring = ring.flatten(1).sum(dim=1).clamp_min(1)
        uu = torch.arange(w, device=dev, dtype=torch.float64).view(1, 1, w)
        vv = torch.arange(h, device=dev, dtype=torch.float64).view(1, h, 1)
        center = torch.stack([(ring * uu).sum(dim=(1, 2)), (ring * vv).sum(dim=(1, 2))],
                             dim=1) / n_ring[:, None]
        score = ((torch.where(ring, grad, 0.0).flatten(1).sum(dim=1) / n_ring)
                 / (torch.where(ring, threshold, 0.0).flatten(1).sum(dim=1) / n_ring)
                 .clamp_min(float(np.finfo(np.float32).tiny)))

        def pick(t, index):
            return t.gather(1, index[:, None])[:, 0]

        stats = {name: t.cpu().numpy() for name, t in dict(
            n=(area > 0).sum(dim=1), kept=keep.any(dim=1), region=region.flatten(1).sum(dim=1),
            area=pick(area, best), u0=pick(u_min, best), v0=pick(v_min, best),
            u1=pick(u_max, best) + 1, v1=pick(v_max, best) + 1, center=center, score=score,
            big_w=pick(widths, largest), big_h=pick(heights, largest),
            big_area=pick(area, largest)).items()}
        out = []
        for i in range(b):
            n = int(stats["n"][i])
            if n == 0:
                out.append(HighlightDetection.missing(
                    f"no pixel with gradient above mu + {srde.k:g} sigma ({srde.window}x"
                    f"{srde.window} window) in the search region of {int(stats['region'][i])} px"))
                continue
            if not stats["kept"][i]:
                out.append(HighlightDetection.missing(
                    f"no gradient component with extent >= {srde.min_extent_px}x"
                    f"{srde.min_extent_px} px among {n} (largest: {int(stats['big_w'][i])}x"
                    f"{int(stats['big_h'][i])} px, {int(stats['big_area'][i])} px)"))
                continue
            bbox = tuple(int(stats[k][i]) for k in ("u0", "v0", "u1", "v1"))
            out.append(HighlightDetection(True, stats["center"][i].astype(np.float64),
                                          int(stats["area"][i]), bbox, float(stats["score"][i]),
                                          ""))
        return out


def _device(device) -> torch.device:
    try:
        dev = torch.device(device)
    except (TypeError, RuntimeError):
        raise SRDEError(f"device: expected a torch device such as 'cpu' or 'cuda', got "
                        f"{device!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise SRDEError(f"device: expected an available torch device, got {device!r} (CUDA is "
                        "not available)")
    return dev


class BatchedSRDE(SRDE):
    """:class:`~srde_fusion.srde.SRDE` with highlight detection in torch, batched over views.

    Same options, same :meth:`estimate` contract and the same :class:`SRDEResult`; the
    views may also be torch tensors already on the device.

    Parameters
    ----------
    rig : CameraRig
    light : array_like, (3,), optional
    device : str or torch.device
        Where the pixel work runs: ``"cpu"``, ``"cuda"``, ``"cuda:1"``, ...
    **options
        Every keyword option of :class:`~srde_fusion.srde.SRDE` (``method``, ``detector``,
        ``blob_center``, ``refine``, ...). With ``blob_center="lobe"`` the lobe fit itself
        runs on the host, on the chosen blob's crop.

    Raises
    ------
    SRDEError
        As :class:`~srde_fusion.srde.SRDE`, and for a device that is not available.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion.rig import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=400.0, image_size=(96, 64))
    >>> srde = BatchedSRDE(rig, light=[0.05, -0.3, 0.2], device="cpu")
    >>> result = srde.estimate([np.zeros((64, 96), np.uint8)] * 2, np.ones((64, 96), bool))
    >>> result.status, result.reason.split(":")[0]
    ('no_highlight', 'view 0 (left, reference)')
    """

    def __init__(self, rig, light=None, *, device="cpu", **options) -> None:
        super().__init__(rig, light, **options)
        self.device = _device(device)
        self._engine = _Engine(self, self.device)

    def estimate(self, views, mask, *, region=None) -> SRDEResult:
        """Estimate the object's plane and disparity; see :meth:`SRDE.estimate`.

        Parameters
        ----------
        views : sequence of N images, or torch.Tensor (N, H, W) or (N, H, W, 3)
            numpy images as :meth:`SRDE.estimate` takes them, or uint8 / float (values in
            [0, 1]) tensors on any device (moved to this estimator's device if elsewhere).
        mask : numpy.ndarray, (H, W) bool
        region : numpy.ndarray, (H, W) bool, optional

        Returns
        -------
        SRDEResult

        Raises
        ------
        ImageError
            Wrong number, size, dtype or values of the views.
        MaskError
            ``mask`` (or ``region``) has the wrong shape or dtype, or is empty.
        """
        return self._estimate(self._device_views(views), mask, region)

    # ------------------------------------------------------------------ steps
    def _device_views(self, views) -> _DeviceViews:
        rig = self.rig
        if isinstance(views, torch.Tensor) or (
                isinstance(views, Sequence) and len(views) > 0
                and all(isinstance(v, torch.Tensor) for v in views)):
            tensors = [self._check_tensor(v, f"views[{i}]") for i, v in enumerate(views)]
            if len(tensors) != rig.n_cameras:
                raise ImageError(f"views: expected {rig.n_cameras} images (one per rig camera), "
                                 f"got {len(tensors)}")
            return _DeviceViews(tensors, None)
        host = check_views(views, rig.n_cameras, rig.image_size)
        # from_numpy shares memory: on the CPU nothing is copied.
        tensors = [torch.from_numpy(np.ascontiguousarray(v)).to(self.device) for v in host]
        return _DeviceViews(tensors, list(host))

    def _check_tensor(self, view: torch.Tensor, name: str) -> torch.Tensor:
        w, h = self.rig.image_size
        if view.dim() == 3 and view.shape[2] == 1:
            view = view[:, :, 0]
        if not (view.dim() == 2 or (view.dim() == 3 and view.shape[2] == 3)):
            raise ImageError(f"{name}: expected shape (H, W) or (H, W, 3), got "
                             f"{tuple(view.shape)}")
        if tuple(view.shape[:2]) != (h, w):
            raise ImageError(f"{name}: expected images of the rig's size {w}x{h}, got "
                             f"{view.shape[1]}x{view.shape[0]}")
        if view.dtype == torch.uint8:
            return view.to(self.device)
        if not view.is_floating_point():
            raise ImageError(f"{name}: expected uint8 or float values in [0, 1], got {view.dtype}")
        view = view.to(self.device, torch.float32)
        if not bool(torch.isfinite(view).all()):
            raise ImageError(f"{name}: expected finite float values in [0, 1], got NaN or inf")
        lo, hi = float(view.min()), float(view.max())
        if lo < 0.0 or hi > 1.0:
            raise ImageError(f"{name}: expected float values in [0, 1], got [{lo:g}, {hi:g}]")
        return view

    def _detect_view(self, views: _DeviceViews, j: int, region: np.ndarray,
                     level: float | None = None) -> HighlightDetection:
        return self._engine.detect(views.tensors, [(j, region, level)])[0]

    def _detect_others(self, views: _DeviceViews, ref_det: HighlightDetection,
                       search: np.ndarray) -> list[HighlightDetection]:
        rig = self.rig
        others = [j for j in range(rig.n_cameras) if j != rig.reference]
        candidates = {j: self._candidates(j, ref_det, search) for j in others}
        reachable = [(j, c) for j, c in candidates.items() if c is not None]
        regions = {}
        if reachable:
            best = self._engine.brightest(views.tensors, reachable)
            regions = {j: self._region_at(c, b, search)
                       for (j, c), b in zip(reachable, best, strict=True)}
        # One level for all views: an asymmetric lobe's centroid depends on it.
        level = None if np.isnan(ref_det.level) else ref_det.level
        items = [(j, r, level) for j, r in regions.items() if r.any()]
        found = {}
        if items:
            found = dict(zip([j for j, _, _ in items], self._engine.detect(views.tensors, items),
                             strict=True))
        detections = []
        for j in range(rig.n_cameras):
            if j == rig.reference:
                detections.append(ref_det)
            else:
                detections.append(found[j] if j in found else self._off_object())
        return detections
