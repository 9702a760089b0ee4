"""The torch detector backend: SRDE's pixel work batched over the views, on any device.

:class:`TorchBackend` implements :class:`~srde_fusion.srde.backends.HighlightBackend` with
torch: luminance (sRGB decoding through a table), the brightness search along each
baseline (Gaussian smoothing), and highlight detection (thresholds, medians, 8-connected
components, centroids; the paper detector's Sobel gradient and box statistics). The
reference view is processed first; all other views of a frame then go through in one
batch. Views given as tensors are read where they are, so on a GPU the images never leave
it. What needs only a few numbers per view stays in numpy on the host (candidate
positions, search discs, the decisions of :mod:`~srde_fusion.srde.highlight`).

Separable filters (Gaussian, Sobel, box) run as kornia's separable filter on GPUs and as
sums of shifted slices on the CPU, where torch's convolutions are slow for thin kernels;
connected components are labelled by :func:`label_components` (max propagation with
pointer jumping), inside the bounding box of the foreground only. The long Gaussian of
the baseline search is evaluated only at the candidate pixels.

Results agree with the numpy backend: each crop is extended at its own edges the way
OpenCV extends it (symmetric for the Gaussian smoothing, reflect-101 for the Sobel and box
filters), so the two differ only in the order of floating-point sums. That can flip a
comparison that sits exactly on a threshold, nothing more.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from kornia.filters import get_spatial_gradient_kernel2d

from .._checks import check_views
from ..errors import ImageError, SRDEError
from ..geometry import CameraRig
from ..imaging import REC709_LUMA, SATURATION_LEVEL_U8, SRGB_TO_LINEAR_U8
from .backends import DetectionRequest, sample_grid, smooth_samples_at
from .config import (
    BLOB_LEVEL,
    MIN_CORE_PX,
    PEAK_SMOOTHING_SIGMA_PX,
    WHITE_FLOOR,
    WHITE_SIGMA_PX,
    DetectorConfig,
)
from .highlight import (
    HighlightDetection,
    blob_rejection,
    grown_box,
    lobe_center,
    paper_rejection,
    search_box,
)
from .search import Candidates
from .torch_ops import (
    bbox_of,
    crop_to_foreground,
    extend_borders,
    filter_valid,
    gaussian_kernel,
    label_components,
    median_of,
    reflect_index,
    smooth_at,
    weighted_centroids,
)

__all__ = [
    "TorchBackend",
]

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


class TorchBackend:
    """Highlight detection in torch, batched over the views, on any device.

    Parameters
    ----------
    rig : CameraRig
    config : DetectorConfig
    white_references : Views, optional
        Validated white-reference images, one per camera.
    device : str or torch.device
        Where the pixel work runs: ``"cpu"``, ``"cuda"``, ``"cuda:1"``, ...

    Raises
    ------
    SRDEError
        The device is not a torch device or is not available.
    """

    def __init__(self, rig: CameraRig, config: DetectorConfig, white_references=None, *,
                 device="cpu") -> None:
        device = _device(device)
        self.rig = rig
        self.config = config
        self.device = device
        self.encoding = config.encoding
        self.lut = torch.from_numpy(SRGB_TO_LINEAR_U8).to(device)
        self.luma = torch.from_numpy(REC709_LUMA).to(device)
        self.blob_kernel = gaussian_kernel(PEAK_SMOOTHING_SIGMA_PX, device)
        self.white_kernel = gaussian_kernel(WHITE_SIGMA_PX, device)
        self.whites = None
        if white_references is not None:
            self.whites = [torch.from_numpy(np.ascontiguousarray(r)).to(device)
                           for r in white_references]

    # ------------------------------------------------------------------ protocol
    def prepare(self, views) -> _DeviceViews:
        """Hold a frame's views on the device (see :meth:`SRDE.estimate`).

        Parameters
        ----------
        views : sequence of N images, or torch.Tensor (N, H, W) or (N, H, W, 3)
            numpy images, or uint8 / float (values in [0, 1]) tensors on any device (moved
            to this backend's device if elsewhere).
        """
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
        return _DeviceViews(tensors, host)

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

    # ------------------------------------------------------------------ pixels
    def crops(self, images: Sequence[torch.Tensor], views, boxes) -> _Crops:
        """Cut ``(u0, v0, u1, v1)`` boxes out of views, padded to the largest box."""
        boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 4)
        sizes = np.stack([boxes[:, 3] - boxes[:, 1], boxes[:, 2] - boxes[:, 0]], axis=1)
        hm, wm = (int(s) for s in sizes.max(axis=0))
        out = []
        for j, (u0, v0, _, _), (h, w) in zip(views, boxes, sizes, strict=True):
            # Beyond its own size a crop repeats itself; those pixels are never results.
            rows = torch.from_numpy(v0 + reflect_index(0, hm, int(h), "symmetric"))
            cols = torch.from_numpy(u0 + reflect_index(0, wm, int(w), "symmetric"))
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
        white = extend_borders(white, crops.sizes, pad, "symmetric")
        white = filter_valid(white, self.white_kernel[0], self.white_kernel[0])
        return lum / white.clamp_min(WHITE_FLOOR)

    def smooth(self, lum: torch.Tensor, sizes: np.ndarray, kernel: torch.Tensor) -> torch.Tensor:
        """Gaussian smoothing of each crop with OpenCV's symmetric border, ``(B, h, w)``."""
        x = extend_borders(lum, sizes, kernel.shape[1] // 2, "symmetric")
        return filter_valid(x, kernel[0], kernel[0])

    # ------------------------------------------------------------------ search
    def brightest(self, frame: _DeviceViews, candidates: Sequence[tuple[int, Candidates]]
                  ) -> list[int]:
        """Index of the brightest candidate of each view (see ``SRDE._search_region``).

        Parameters
        ----------
        images : sequence of torch.Tensor
        candidates : list of (int, _Candidates)
            One entry per view; all share the reference blob, hence the smoothing.
        """
        sigma = candidates[0][1].sigma_px
        best: dict[int, int] = {}
        full = []  # the views whose crop is smoothed at every pixel, on the device
        for i, (j, c) in enumerate(candidates):
            grid = sample_grid((*c.lo, *c.hi), sigma)
            if grid is None:
                full.append(i)
                continue
            # A large blob is smoothed from a grid of the crop's pixels: the grid is read
            # on the device and smoothed on the host with the numpy backend's function.
            rows, cols, _ = grid
            samples = self.luminance(frame.tensors[j][rows, cols][None])[0].cpu().numpy()
            brightness = np.full(c.w_v.size, -np.inf)
            brightness[c.ok] = smooth_samples_at(np.ascontiguousarray(samples), grid,
                                                 c.pix[c.ok], sigma)
            best[i] = int(np.argmax(brightness))
        if full:
            searches = [candidates[i] for i in full]
            crops = self.crops(frame.tensors, [j for j, _ in searches],
                               [(*c.lo, *c.hi) for _, c in searches])
            kernel = gaussian_kernel(sigma, self.device)
            extended = extend_borders(self.luminance(crops.pixels), crops.sizes,
                                      kernel.shape[1] // 2, "symmetric")
            values = []
            for ext, (_, c) in zip(extended, searches, strict=True):
                brightness = torch.full((c.w_v.size,), -math.inf, dtype=torch.float64,
                                        device=self.device)
                local = c.pix[c.ok] - np.asarray(c.lo)
                smooth = smooth_at(ext, local, kernel[0])
                brightness[torch.from_numpy(np.flatnonzero(c.ok)).to(self.device)] = smooth.double()
                values.append(brightness)
            # argmax returns the first of equal maxima, as numpy's does.
            argmax = torch.stack([b.argmax() for b in values]).tolist()
            best.update(zip(full, (int(a) for a in argmax), strict=True))
        return [best[i] for i in range(len(candidates))]

    # ------------------------------------------------------------------ detection
    def detect(self, frame: _DeviceViews, requests: Sequence[DetectionRequest]
               ) -> list[HighlightDetection]:
        """Detect the highlight of several views at once (regions must not be empty)."""
        if not requests:
            return []
        images = frame.tensors
        shape = (self.rig.height, self.rig.width)
        boxes = [search_box(r.region, self.config.margin_px) if r.bbox is None
                 else grown_box(r.bbox, self.config.margin_px, shape) for r in requests]
        crops = self.crops(images, [r.view for r in requests], boxes)
        b, hm, wm = crops.pixels.shape[:3]
        region_np = np.zeros((b, hm, wm), dtype=bool)
        for i, (r, (u0, v0, u1, v1)) in enumerate(zip(requests, boxes, strict=True)):
            region_np[i, :v1 - v0, :u1 - u0] = r.region[v0:v1, u0:u1]
        region_t = torch.from_numpy(region_np).to(self.device)
        lum = self.normalized_luminance(images, crops)
        if self.config.method == "paper":
            found = self._paper(lum, region_t, crops.sizes)
        else:
            found = self._blob(lum, region_t, crops, [r.level for r in requests], region_np)
        return [det.shifted(origin) for det, origin in zip(found, crops.origins, strict=True)]

    def _blob(self, lum, region, crops: _Crops, levels, region_np) -> list[HighlightDetection]:
        """Run the blob detector on a batch of crops (as :func:`detect_in_view` does)."""
        config = self.config
        b, h, w = lum.shape
        dev = self.device
        smooth = self.smooth(lum, crops.sizes, self.blob_kernel)
        background = median_of(lum, region)
        peak = torch.where(region, smooth, -torch.inf).flatten(1).amax(dim=1).double()
        contrast = peak - background
        given = torch.tensor([math.nan if lv is None else lv for lv in levels],
                             dtype=torch.float64, device=dev)
        level = torch.where(torch.isnan(given), background + BLOB_LEVEL * contrast, given)
        excess = (lum - level.float()[:, None, None]) * region
        layers = [excess]
        if config.blob_center == "core":
            layers.append(self.saturated(crops.pixels))
        origins, foreground, excess, *saturated = crop_to_foreground(excess > 0, *layers)
        b, h, w = foreground.shape
        labels = label_components(foreground).flatten(1)                # (B, h w)
        light = torch.zeros(b, h * w + 1, dtype=torch.float64, device=dev)
        light.scatter_add_(1, labels, excess.clamp_min(0).flatten(1).double())
        light[:, 0] = -1.0
        best = light.argmax(dim=1)
        blob = (labels == best[:, None]).view(b, h, w) & foreground
        uu = torch.arange(w, device=dev, dtype=torch.float64).view(1, 1, w)
        vv = torch.arange(h, device=dev, dtype=torch.float64).view(1, h, 1)
        center = weighted_centroids(torch.where(blob, excess.double(), 0.0), uu, vv)
        if saturated:
            core = blob & saturated[0]
            n_core = core.flatten(1).sum(dim=1)
            center = torch.where((n_core >= MIN_CORE_PX)[:, None],
                                 weighted_centroids(core.double(), uu, vv), center)
        stats = {name: t.cpu().numpy() for name, t in dict(
            background=background, peak=peak, contrast=contrast, level=level,
            any=foreground.flatten(1).any(dim=1), area=blob.flatten(1).sum(dim=1),
            center=center, bbox=bbox_of(blob)).items()}
        out = []
        for i in range(b):
            bg, pk, ct, lv = (float(stats[k][i]) for k in ("background", "peak", "contrast",
                                                            "level"))
            area = int(stats["area"][i])
            reason = blob_rejection(config, background=bg, peak=pk, level=lv,
                                    any_above=bool(stats["any"][i]), area_px=area)
            if reason:
                out.append(HighlightDetection.missing(reason))
                continue
            (u0, v0), (bu0, bv0, bu1, bv1) = origins[i], stats["bbox"][i]
            center_uv = stats["center"][i] + np.array([u0, v0], dtype=np.float64)
            if config.blob_center == "lobe":
                full = np.zeros(lum.shape[1:], dtype=bool)
                box = blob[i, :bv1, :bu1].cpu().numpy()
                full[v0:v0 + box.shape[0], u0:u0 + box.shape[1]] = box
                center_uv = self._lobe(lum[i], crops.pixels[i], region_np[i], full, bg, ct,
                                       center_uv)
            out.append(HighlightDetection(True, center_uv, area, (int(bu0 + u0), int(bv0 + v0),
                                          int(bu1 + u0), int(bv1 + v0)), ct, "", lv))
        return out

    def _lobe(self, lum, pixels, region, blob, background, contrast, fallback) -> np.ndarray:
        """Fit the lobe centre on the host, from this crop (a least-squares fit)."""
        fitted = lobe_center(lum.cpu().numpy(), self.saturated(pixels[None])[0].cpu().numpy(),
                              region, blob, background, contrast)
        return fallback if fitted is None else fitted

    def _paper(self, lum, region, sizes: np.ndarray) -> list[HighlightDetection]:
        """Run the paper's gradient detector on a batch of crops (as :func:`detect_in_view`)."""
        config = self.config
        b, h, w = lum.shape
        dev = self.device
        half = config.window // 2
        # Sobel then box statistics, both with reflect-101 borders: |gradient| of the
        # extended crop is the extension of the crop's |gradient|, so one extension does.
        x = extend_borders(lum, sizes, half + 1, "reflect101")
        sobel = get_spatial_gradient_kernel2d("sobel", 1).to(dev, torch.float32)
        derivative, smoothing = sobel[0, 0], sobel[0, :, 2]             # [-1, 0, 1], [1, 2, 1]
        gx = filter_valid(x, derivative, smoothing)
        gy = filter_valid(x, smoothing, derivative)
        grad = torch.sqrt(gx * gx + gy * gy)                            # (B, h + 2 half, ...)
        box = torch.full((config.window,), 1.0 / config.window, device=dev)
        mean = filter_valid(grad, box, box)
        mean_sq = filter_valid(grad * grad, box, box)
        grad = grad[:, half:half + h, half:half + w]
        std = torch.sqrt(torch.clamp(mean_sq - mean * mean, min=0.0))
        threshold = mean + config.k * std
        n_region = region.flatten(1).sum(dim=1)
        origins, candidates, grad, threshold = crop_to_foreground(region & (grad > threshold), grad,
                                                      threshold)
        b, h, w = candidates.shape
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
        keep = (widths >= config.min_extent_px) & (heights >= config.min_extent_px) & (area > 0)
        best = torch.where(keep, area, -1).argmax(dim=1)
        largest = area.argmax(dim=1)
        ring = (labels == best[:, None]).view(b, h, w) & candidates
        n_ring = ring.flatten(1).sum(dim=1).clamp_min(1)
        uu = torch.arange(w, device=dev, dtype=torch.float64).view(1, 1, w)
        vv = torch.arange(h, device=dev, dtype=torch.float64).view(1, h, 1)
        score = ((torch.where(ring, grad, 0.0).flatten(1).sum(dim=1) / n_ring)
                 / (torch.where(ring, threshold, 0.0).flatten(1).sum(dim=1) / n_ring)
                 .clamp_min(float(np.finfo(np.float32).tiny)))

        def pick(t, index):
            return t.gather(1, index[:, None])[:, 0]

        stats = {name: t.cpu().numpy() for name, t in dict(
            n=(area > 0).sum(dim=1), kept=keep.any(dim=1), region=n_region,
            area=pick(area, best), u0=pick(u_min, best), v0=pick(v_min, best),
            u1=pick(u_max, best) + 1, v1=pick(v_max, best) + 1,
            center=weighted_centroids(ring.double(), uu, vv), score=score,
            big_w=pick(widths, largest), big_h=pick(heights, largest),
            big_area=pick(area, largest)).items()}
        out = []
        for i in range(b):
            reason = paper_rejection(
                config, n_components=int(stats["n"][i]), any_kept=bool(stats["kept"][i]),
                region_px=int(stats["region"][i]),
                largest=(int(stats["big_w"][i]), int(stats["big_h"][i]),
                         int(stats["big_area"][i])))
            if reason:
                out.append(HighlightDetection.missing(reason))
                continue
            u0, v0 = (int(o) for o in origins[i])
            bbox = (int(stats["u0"][i]) + u0, int(stats["v0"][i]) + v0,
                    int(stats["u1"][i]) + u0, int(stats["v1"][i]) + v0)
            center_uv = stats["center"][i] + np.array([u0, v0], dtype=np.float64)
            out.append(HighlightDetection(True, center_uv, int(stats["area"][i]), bbox,
                                          float(stats["score"][i]), ""))
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
