"""The mask stage: where the flat glossy objects are in the reference view.

A *masker* is any callable ``masker(views, rig) -> list of (H, W) bool`` giving one mask
per reflective object in the reference view (DESIGN §5). Three come with the library:

- :class:`UserMasks` — masks you already have (a label image file or arrays);
- :class:`HighlightSegmenter` — built in, needs no training data: grows a textureless
  region around each specular highlight of the reference view and keeps it only if
  every other view shows the same highlight where a single 3D point would put it;
- :class:`OnnxMasker` — any segmentation network exported to ONNX.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy import ndimage

from .._checks import check_views
from ..errors import BackboneError, FileFormatError, MaskError, SRDEError
from ..geometry import CameraRig
from ..imaging import luminance, saturation_mask, to_float
from ..io import masks_from_labels, read_mask

__all__ = [
    "Masker",
    "UserMasks",
    "HighlightSegmenter",
    "SegmenterDiagnostics",
    "OnnxMasker",
]

Masker = Callable[[Sequence[np.ndarray], CameraRig], list]


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    return type(value).__name__


def _labels_to_masks(labels: np.ndarray, name: str) -> list[np.ndarray]:
    """Split labels into masks, also accepting float arrays holding whole numbers."""
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
    return masks_from_labels(labels)


def _split_components(mask: np.ndarray, min_area_px: int) -> list[np.ndarray]:
    """Split into 8-connected components of at least ``min_area_px``, raster order."""
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return [comp == i for i in range(1, n) if stats[i, cv2.CC_STAT_AREA] >= min_area_px]


def _check_rig_shape(masks: list[np.ndarray], rig: CameraRig, name: str) -> None:
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
    split_components : bool
        Split each label into its connected components (for binary masks that hold
        several objects).
    min_area_px : int
        With ``split_components``, components smaller than this are dropped.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(4, 3))
    >>> labels = np.array([[0, 1, 1, 0], [0, 0, 2, 2], [0, 0, 0, 0]])
    >>> [int(m.sum()) for m in UserMasks(labels)(None, rig)]
    [2, 2]
    """

    def __init__(self, source: Any, *, split_components: bool = False, min_area_px: int = 1
                 ) -> None:
        self.source = source
        self.split_components = split_components
        self.min_area_px = int(min_area_px)
        self._masks = self._load(source)
        if split_components:
            self._masks = [c for m in self._masks for c in _split_components(m, self.min_area_px)]
        if not self._masks:
            raise MaskError(f"masks: expected at least one object (a non-zero label), got none "
                            f"in {self._where(source)}")

    @staticmethod
    def _where(source: Any) -> str:
        return repr(str(source)) if isinstance(source, (str, os.PathLike)) else _describe(source)

    @staticmethod
    def _load(source: Any) -> list[np.ndarray]:
        if isinstance(source, (str, os.PathLike)):
            path = Path(source)
            if not path.is_file():
                raise FileFormatError(f"mask file: expected an existing file, got {str(path)!r}")
            if path.suffix.lower() == ".npy":
                try:
                    labels = np.load(path, allow_pickle=False)
                except ValueError as exc:
                    raise FileFormatError(f"{path}: expected a .npy label array, got {exc}"
                                          ) from None
            else:
                labels = read_mask(path)
            if labels.ndim != 2:
                raise MaskError(f"{path}: expected an (H, W) label image, got shape {labels.shape}")
            return _labels_to_masks(labels, str(path))
        if isinstance(source, np.ndarray):
            if source.ndim == 2:
                return _labels_to_masks(source, "masks")
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
                out.append(np.logical_or.reduce(found))
            return out
        raise MaskError(f"masks: expected a mask file path, a label array or a list of masks, "
                        f"got {_describe(source)}")

    def __call__(self, views: Any, rig: CameraRig) -> list[np.ndarray]:
        """Return the masks, checked against the rig's image size (``views`` is unused).

        Returns
        -------
        list of numpy.ndarray, (H, W), bool
            Fresh copies, one per object.
        """
        _check_rig_shape(self._masks, rig, "masks")
        return [m.copy() for m in self._masks]

    def __repr__(self) -> str:
        return f"UserMasks({self._where(self.source)}, {len(self._masks)} object(s))"


# --------------------------------------------------------------------------- segmenter
@dataclass(frozen=True)
class SegmenterDiagnostics:
    """Why each highlight seed of the reference view was kept or dropped.

    Attributes
    ----------
    seeds_uv : numpy.ndarray, (S, 2), float64
        Centre of each seed blob in the reference view, pixels.
    kept : tuple of bool
        Whether each seed produced an object mask.
    reasons : tuple of str
        One line per seed.
    inverse_depth_per_m : tuple of float
        ``1 / z`` of the highlight's 3D point that the views agreed on (NaN if none).
    """

    seeds_uv: np.ndarray
    kept: tuple[bool, ...]
    reasons: tuple[str, ...]
    inverse_depth_per_m: tuple[float, ...]


@dataclass(frozen=True)
class _Blob:
    center_uv: np.ndarray  # (2,)
    area_px: int
    mask: np.ndarray  # (H, W) bool


#: Distances from a seed (pixels) between which the object's own noise level is sampled.
_NOISE_ANNULUS_PX = (5.0, 30.0)
#: Percentile of the fine-scale contrast in that annulus taken as the surface's noise:
#: low enough to ignore the highlight's fall-off and any edge the annulus crosses.
_NOISE_PERCENTILE = 25.0
#: A ring around the seed counts as quiet when this fraction of it is below the threshold.
_QUIET_RING_FRACTION = 0.9
#: The highlight's fall-off ends at the first run of this many quiet rings.
_QUIET_RINGS = 3


class HighlightSegmenter:
    """Built-in mask stage: textureless regions around cross-view-consistent highlights.

    Needs no training data. For the reference view:

    1. **Seeds** — bright blobs of linear luminance (at least ``seed_luminance``, or
       clipped) of at least ``min_seed_area_px``.
    2. **Consistency** — in a rectified array a highlight at ``(u, v)`` in the reference
       view appears in camera ``j`` at ``(u - fx·dX_j/z, v - fy·dY_j/z)`` for the one
       depth ``z > 0`` of its 3D point (the virtual light). A seed is kept only if every
       other view has a bright blob at such a place, for a common ``z``.
    3. **Growth** — over the textureless surface around the seed. Texture and edges are
       measured as fine-scale contrast, ``max_c |G_s1 * I_c - G_s2 * I_c|`` (a difference
       of Gaussians per encoded colour channel, averaged over a small box), which stays
       low on the highlight's smooth fall-off but not on a step. The threshold is
       ``noise_factor`` times the surface's own noise level, read near the seed (scales
       are set for objects of a few hundred pixels across in 640x480 images; scale the
       pixel options with the image); rings around the seed are passable
       until the first few quiet ones, so the clipped core's sharp rim does not wall the
       seed in. The region is the seed's 8-connected component of passable pixels,
       opened (cuts thin leaks through gaps in the outline) and with holes filled.
    4. **Boundary** — the growth stops a few pixels short of the outline (the filter's
       reach); a marker-controlled watershed on the gradient magnitude, between the
       region and everything ``refine_band_px`` beyond it, puts the boundary on the
       outline's ridge.

    Parameters
    ----------
    seed_luminance : float
        Linear luminance in (0, 1] at or above which a pixel can seed a highlight.
    min_seed_area_px : int
        Smallest seed blob, pixels.
    contrast_sigmas_px : (float, float)
        The two Gaussian scales of the fine-scale contrast, pixels.
    texture_window_px : int
        Side of the box the contrast is averaged over (texture energy), pixels; faint
        background texture rises above the noise floor on average where single pixels
        do not.
    noise_factor : float
        Threshold on the contrast, in multiples of the surface's noise level.
    min_threshold, max_threshold : float
        Bounds of that threshold (encoded intensity in [0, 1]). A surface noisier than
        ``max_threshold / noise_factor`` is texture, not a glossy object: the seed is
        dropped.
    lobe_max_radius_px : int
        How far from the seed the highlight's fall-off may reach, pixels.
    opening_radius_px : int
        Radius of the opening that cuts thin leaks, pixels.
    refine_band_px : int
        Width of the band the boundary is searched in, pixels (0 = no refinement).
    min_region_px : int
        Smallest object, pixels.
    min_region_to_seed : float
        An object must be at least this many times its seed's area.
    max_region_fraction : float
        Largest object as a fraction of the image (larger = leaked into the background).
    consistency_tol_px : float
        How far a blob in another view may lie from where the common 3D point puts it,
        pixels ...
    consistency_tol_rel : float
        ... or this fraction of the seed's equivalent radius, whichever is larger (a blob
        cut by the object's edge in one view shifts its centre).
    min_consistent_views : int or None
        Views besides the reference that must agree; all of them by default.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(64, 48))
    >>> views = [np.full((48, 64, 3), 40, np.uint8)] * 2
    >>> HighlightSegmenter()(views, rig)  # no highlight, no object
    []
    """

    def __init__(self, *, seed_luminance: float = 0.8, min_seed_area_px: int = 6,
                 contrast_sigmas_px: tuple[float, float] = (1.0, 3.0),
                 texture_window_px: int = 3, noise_factor: float = 2.5,
                 min_threshold: float = 0.002, max_threshold: float = 0.04,
                 lobe_max_radius_px: int = 40, opening_radius_px: int = 2,
                 refine_band_px: int = 8, min_region_px: int = 200,
                 min_region_to_seed: float = 4.0, max_region_fraction: float = 0.6,
                 consistency_tol_px: float = 2.0, consistency_tol_rel: float = 0.25,
                 min_consistent_views: int | None = None) -> None:
        if not 0.0 < seed_luminance <= 1.0:
            raise SRDEError(f"seed_luminance: expected a value in (0, 1], got {seed_luminance!r}")
        if not 0.0 < max_region_fraction <= 1.0:
            raise SRDEError(f"max_region_fraction: expected a value in (0, 1], got "
                             f"{max_region_fraction!r}")
        s1, s2 = (float(s) for s in contrast_sigmas_px)
        if not 0.0 < s1 < s2:
            raise SRDEError(f"contrast_sigmas_px: expected 0 < s1 < s2, got "
                             f"{contrast_sigmas_px!r}")
        if not 0.0 <= min_threshold <= max_threshold:
            raise SRDEError(f"min_threshold, max_threshold: expected 0 <= min <= max, got "
                             f"{min_threshold!r}, {max_threshold!r}")
        self.seed_luminance = float(seed_luminance)
        self.min_seed_area_px = int(min_seed_area_px)
        self.contrast_sigmas_px = (s1, s2)
        self.texture_window_px = int(texture_window_px)
        self.noise_factor = float(noise_factor)
        self.min_threshold = float(min_threshold)
        self.max_threshold = float(max_threshold)
        self.lobe_max_radius_px = int(lobe_max_radius_px)
        self.opening_radius_px = int(opening_radius_px)
        self.refine_band_px = int(refine_band_px)
        self.min_region_px = int(min_region_px)
        self.min_region_to_seed = float(min_region_to_seed)
        self.max_region_fraction = float(max_region_fraction)
        self.consistency_tol_px = float(consistency_tol_px)
        self.consistency_tol_rel = float(consistency_tol_rel)
        self.min_consistent_views = min_consistent_views
        self.last_diagnostics: SegmenterDiagnostics | None = None

    def __call__(self, views: Sequence[np.ndarray], rig: CameraRig) -> list[np.ndarray]:
        """Find the glossy objects in the reference view.

        Parameters
        ----------
        views : sequence of numpy.ndarray, (H, W, 3) uint8
            One image per rig camera.
        rig : CameraRig

        Returns
        -------
        list of numpy.ndarray, (H, W), bool
            One mask per object, seeds in raster order. The reasons for every seed
            (kept or not) are in :attr:`last_diagnostics`.
        """
        masks, diagnostics = self.segment(views, rig)
        self.last_diagnostics = diagnostics
        return masks

    def segment(self, views: Sequence[np.ndarray], rig: CameraRig
                ) -> tuple[list[np.ndarray], SegmenterDiagnostics]:
        """Find the objects, and say why each seed was kept or dropped.

        Returns
        -------
        masks : list of numpy.ndarray, (H, W), bool
        diagnostics : SegmenterDiagnostics
        """
        views = check_views(views, rig.n_cameras, rig.image_size)
        ref = views[rig.reference]
        seeds = self._blobs(ref, rig.image_encoding)
        blobs_per_view = {j: self._blobs(views[j], rig.image_encoding)
                          for j in range(rig.n_cameras) if j != rig.reference} if seeds else {}
        contrast = self._contrast(ref) if seeds else None

        masks: list[np.ndarray] = []
        taken = np.zeros(ref.shape[:2], dtype=bool)
        kept, reasons, inv_depths = [], [], []
        h, w = ref.shape[:2]
        for blob in seeds:
            inv_depth, why, region = np.nan, "", None
            if np.any(taken[blob.mask]):
                why = "inside an object already found"
            if not why:
                inv_depth, why = self._consistent(blob, blobs_per_view, rig)
            if not why:
                region, why = self._grow(blob, ref, contrast)
            if not why:
                region &= ~taken
                n = int(np.count_nonzero(region))
                if n < self.min_region_px:
                    why = f"region of {n} px < min_region_px {self.min_region_px}"
                elif n < self.min_region_to_seed * blob.area_px:
                    why = (f"region of {n} px is < {self.min_region_to_seed:g} x the highlight's "
                           f"{blob.area_px} px: no textureless surface around it")
                elif n > self.max_region_fraction * h * w:
                    why = (f"region of {n} px covers {n / (h * w):.0%} of the image: the "
                           f"object's outline is not closed")
            kept.append(not why)
            inv_depths.append(inv_depth)
            if why:
                reasons.append(why)
                continue
            reasons.append(f"object of {int(region.sum())} px; the views agree on a highlight at "
                           f"1/z = {inv_depth:.3f} /m")
            masks.append(region)
            taken |= region
        centers = np.array([b.center_uv for b in seeds]) if seeds else np.zeros((0, 2))
        return masks, SegmenterDiagnostics(centers, tuple(kept), tuple(reasons), tuple(inv_depths))

    # ------------------------------------------------------------------ steps
    def _blobs(self, image: np.ndarray, encoding: str) -> list[_Blob]:
        lum = luminance(image, encoding)
        bright = (lum >= self.seed_luminance) | saturation_mask(image)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(bright.astype(np.uint8),
                                                             connectivity=8)
        blobs = []
        for i in range(1, n):  # a handful of blobs, not pixels
            area = int(stats[i, cv2.CC_STAT_AREA])
            if area < self.min_seed_area_px:
                continue
            mask = comp == i
            weight = lum[mask].astype(np.float64)
            vs, us = np.nonzero(mask)
            center = np.array([np.average(us, weights=weight), np.average(vs, weights=weight)])
            blobs.append(_Blob(center, area, mask))
        return blobs

    def _contrast(self, image: np.ndarray) -> np.ndarray:
        """Fine-scale contrast: max over channels of a difference of Gaussians, (H, W)."""
        # Encoded values: their noise is closer to uniform across brightness than the
        # linear values' after an sRGB camera curve, and edges look as the eye sees them.
        f = to_float(image)
        s1, s2 = self.contrast_sigmas_px
        dog = np.abs(cv2.GaussianBlur(f, (0, 0), s1) - cv2.GaussianBlur(f, (0, 0), s2))
        contrast = dog.max(axis=2) if dog.ndim == 3 else dog
        if self.texture_window_px > 1:
            # Texture energy: faint texture stays above the noise floor on average even
            # where single pixels dip below it.
            contrast = cv2.blur(contrast, (self.texture_window_px, self.texture_window_px))
        return contrast

    def _gradient(self, image: np.ndarray) -> np.ndarray:
        f = cv2.GaussianBlur(to_float(image), (0, 0), self.contrast_sigmas_px[0])
        if f.ndim == 2:
            f = f[:, :, None]
        mags = [cv2.magnitude(cv2.Sobel(f[:, :, c], cv2.CV_32F, 1, 0, ksize=3),
                              cv2.Sobel(f[:, :, c], cv2.CV_32F, 0, 1, ksize=3))
                for c in range(f.shape[2])]
        return np.max(mags, axis=0)

    def _grow(self, blob: _Blob, image: np.ndarray, contrast: np.ndarray
              ) -> tuple[np.ndarray | None, str]:
        dist = ndimage.distance_transform_edt(~blob.mask)
        lo, hi = _NOISE_ANNULUS_PX
        noise = float(np.percentile(contrast[(dist > lo) & (dist <= hi)], _NOISE_PERCENTILE))
        threshold = self.noise_factor * noise
        if threshold > self.max_threshold:
            return None, (f"textured surroundings: contrast threshold {threshold:.4f} > "
                          f"max_threshold {self.max_threshold:g}")
        threshold = max(threshold, self.min_threshold)
        passable = contrast < threshold

        # The highlight's fall-off: rings around the seed until a run of quiet ones.
        r_max = self.lobe_max_radius_px
        ring = np.floor(dist).astype(np.int64)
        near = (ring >= 1) & (ring <= r_max)
        count = np.bincount(ring[near], minlength=r_max + 1)
        quiet = np.bincount(ring[near], weights=passable[near], minlength=r_max + 1)
        quiet_fraction = np.where(count > 0, quiet / np.maximum(count, 1), 1.0)
        is_quiet = quiet_fraction >= _QUIET_RING_FRACTION
        runs = np.convolve(is_quiet[1:].astype(int), np.ones(_QUIET_RINGS, int), "valid")
        first = np.flatnonzero(runs == _QUIET_RINGS)
        lobe_radius = int(first[0]) + 1 if first.size else r_max
        passable |= dist <= lobe_radius

        region = _component_with(passable, blob.mask)
        if self.opening_radius_px > 0:
            size = 2 * self.opening_radius_px + 1
            disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
            opened = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_OPEN, disc).astype(bool)
            region = _component_with(opened | blob.mask, blob.mask)
        region = ndimage.binary_fill_holes(region)
        if self.refine_band_px > 0:
            region = self._refine(region, image)
        return region, ""

    def _refine(self, region: np.ndarray, image: np.ndarray) -> np.ndarray:
        """Move the boundary onto the outline's gradient ridge (marker watershed)."""
        from skimage.segmentation import watershed

        band = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * self.refine_band_px + 1,) * 2)
        outer = cv2.dilate(region.astype(np.uint8), band).astype(bool)
        vs, us = np.nonzero(outer)
        h, w = region.shape
        v0, v1 = max(vs.min() - 2, 0), min(vs.max() + 3, h)
        u0, u1 = max(us.min() - 2, 0), min(us.max() + 3, w)
        crop = (slice(v0, v1), slice(u0, u1))
        markers = np.where(region[crop], 1, np.where(outer[crop], 0, 2)).astype(np.int32)
        labels = watershed(self._gradient(image[crop]), markers)
        out = np.zeros_like(region)
        out[crop] = labels == 1
        return ndimage.binary_fill_holes(out)

    def _consistent(self, blob: _Blob, blobs_per_view: dict[int, list[_Blob]],
                    rig: CameraRig) -> tuple[float, str]:
        """Find the highlight's common inverse depth across views, or why there is none."""
        k = rig.intrinsics
        ref_c = rig.reference_center_m
        tol = max(self.consistency_tol_px,
                  self.consistency_tol_rel * float(np.sqrt(blob.area_px / np.pi)))
        # Per view j, the shift c_ref - c_j equals a_j / z with a_j = (fx dX_j, fy dY_j).
        candidates = []  # (view, inverse depth, a_j, shift)
        for j, blobs in blobs_per_view.items():
            d = rig.centers_m[j] - ref_c
            a = np.array([k.fx * d[0], k.fy * d[1]])
            for b in blobs:
                shift = blob.center_uv - b.center_uv
                inv = float(shift @ a / (a @ a))
                if inv > -tol / np.linalg.norm(a):
                    candidates.append((j, max(inv, 0.0), a, shift))
        n_needed = (len(blobs_per_view) if self.min_consistent_views is None
                    else min(self.min_consistent_views, len(blobs_per_view)))
        best_inv, best_views = np.nan, set()
        for _, inv, _, _ in candidates:  # hypotheses: each candidate's depth
            agree = {j for j, _, a, s in candidates if np.linalg.norm(s - a * inv) <= tol}
            if len(agree) > len(best_views):
                best_inv, best_views = inv, agree
        if len(best_views) >= n_needed:
            # Refine: least-squares inverse depth over the agreeing blobs.
            rows = [(a, s) for j, _, a, s in candidates
                    if j in best_views and np.linalg.norm(s - a * best_inv) <= tol]
            num = sum(float(s @ a) for a, s in rows)
            den = sum(float(a @ a) for a, _ in rows)
            return (num / den if den > 0 else best_inv), ""
        missing = sorted(set(blobs_per_view) - best_views)
        return np.nan, (f"views {missing} show no highlight where the reference highlight's 3D "
                        f"point would appear ({len(best_views)} of {n_needed} views agree "
                        f"within {tol:.1f} px)")


def _component_with(passable: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Return the 8-connected components of ``passable`` that touch ``seed``."""
    labels, _ = ndimage.label(passable, structure=np.ones((3, 3), bool))
    ids = np.unique(labels[seed])
    return np.isin(labels, ids[ids > 0])


# --------------------------------------------------------------------------- ONNX masker
class OnnxMasker:
    """Any segmentation network exported to ONNX, as a masker.

    The network takes ``(B, 3, H, W)`` float32 RGB and returns ``(B, 1, H, W)`` (object
    vs background) or ``(B, K, H, W)``. Inputs are resized to ``input_size`` (or the
    model's fixed size) and outputs back to the image size before thresholding.

    Parameters
    ----------
    path : path
        The ``.onnx`` file.
    threshold : float
        Probability above which a pixel is inside (binary and instance outputs).
    output : {"logits", "probabilities"}
        What the network returns: logits (sigmoid for one channel or
        ``layout="instances"``, softmax for classes) or probabilities already.
    layout : {"classes", "instances"}
        For ``K > 1`` channels: ``"classes"`` — channel 0 is background, each pixel takes
        its most probable class and each class splits into connected components;
        ``"instances"`` — each channel is one object's mask. A single channel is always
        a foreground map split into connected components.
    input_size : (int, int), optional
        ``(width, height)`` the network expects; the model's static input size, or the
        image size, by default.
    input_scale : float
        Factor applied to 0..255 pixel values before ``mean`` and ``std``.
    mean, std : (float, float, float)
        Per-channel normalisation after scaling: ``(x * input_scale - mean) / std``.
    min_area_px : int
        Components smaller than this (at image size) are dropped.
    providers : list of str, optional
        onnxruntime execution providers; CPU by default.
    """

    def __init__(self, path: str | os.PathLike, *, threshold: float = 0.5,
                 output: str = "logits", layout: str = "classes",
                 input_size: tuple[int, int] | None = None, input_scale: float = 1.0 / 255.0,
                 mean: Sequence[float] = (0.0, 0.0, 0.0), std: Sequence[float] = (1.0, 1.0, 1.0),
                 min_area_px: int = 64, providers: Sequence[str] | None = None) -> None:
        if output not in ("logits", "probabilities"):
            raise SRDEError(f"output: expected 'logits' or 'probabilities', got {output!r}")
        if layout not in ("classes", "instances"):
            raise SRDEError(f"layout: expected 'classes' or 'instances', got {layout!r}")
        if not 0.0 < threshold < 1.0:
            raise SRDEError(f"threshold: expected a probability in (0, 1), got {threshold!r}")
        path = Path(path)
        if not path.is_file():
            raise FileFormatError(f"segmentation model: expected an existing .onnx file, got "
                                  f"{str(path)!r}")
        import onnxruntime as ort

        try:
            self._session = ort.InferenceSession(
                str(path), providers=list(providers or ["CPUExecutionProvider"]))
        except Exception as exc:  # onnxruntime raises its own types for malformed files
            raise FileFormatError(f"{path}: expected a valid ONNX model, got "
                                  f"{type(exc).__name__}: {str(exc).splitlines()[0]}") from None
        inputs = self._session.get_inputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise BackboneError(f"{path}: expected one (B, 3, H, W) input, got "
                                f"{[(i.name, i.shape) for i in inputs]}")
        self._input_name = inputs[0].name
        static = inputs[0].shape[2:]
        if input_size is None and all(isinstance(s, int) and s > 0 for s in static):
            input_size = (static[1], static[0])
        self.path = path
        self.threshold = float(threshold)
        self.output = output
        self.layout = layout
        self.input_size = None if input_size is None else (int(input_size[0]), int(input_size[1]))
        self.input_scale = float(input_scale)
        self.mean = np.asarray(mean, dtype=np.float32).reshape(3, 1, 1)
        self.std = np.asarray(std, dtype=np.float32).reshape(3, 1, 1)
        self.min_area_px = int(min_area_px)

    def __call__(self, views: Sequence[np.ndarray], rig: CameraRig) -> list[np.ndarray]:
        """Masks of the objects the network finds in the reference view.

        Returns
        -------
        list of numpy.ndarray, (H, W), bool
        """
        views = check_views(views, rig.n_cameras, rig.image_size)
        return self.predict(views[rig.reference])

    def predict(self, image: np.ndarray) -> list[np.ndarray]:
        """Masks for one RGB image.

        Parameters
        ----------
        image : numpy.ndarray, (H, W, 3) uint8

        Returns
        -------
        list of numpy.ndarray, (H, W), bool
        """
        h, w = image.shape[:2]
        rgb = to_float(image) * 255.0 if image.dtype != np.uint8 else image.astype(np.float32)
        if rgb.ndim == 2:
            rgb = np.repeat(rgb[:, :, None], 3, axis=2)
        if self.input_size is not None and self.input_size != (w, h):
            shrink = self.input_size[0] < w
            rgb = cv2.resize(rgb, self.input_size,
                             interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        x = (rgb.transpose(2, 0, 1) * self.input_scale - self.mean) / self.std
        x = x[None].astype(np.float32)  # (3, h, w) -> (1, 3, h, w)
        try:
            out = self._session.run(None, {self._input_name: x})[0]
        except Exception as exc:
            raise BackboneError(f"{self.path}: inference failed on a {tuple(x.shape)} input: "
                                f"{str(exc).splitlines()[0]}") from None
        out = np.asarray(out, dtype=np.float32)
        if out.ndim == 3:
            out = out[:, None]  # (B, H, W) -> (B, 1, H, W)
        if out.ndim != 4 or out.shape[0] != 1:
            raise BackboneError(f"{self.path}: expected an output of shape (1, K, H, W), got "
                                f"{out.shape}")
        maps = out[0]
        n_channels = maps.shape[0]
        if n_channels > 1 and self.layout == "classes":
            probs = _softmax(maps) if self.output == "logits" else maps
        else:
            probs = _sigmoid(maps) if self.output == "logits" else maps
        # (K, h', w') -> (K, H, W); probabilities resize smoothly, labels would not.
        if probs.shape[1:] != (h, w):
            probs = np.stack([cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR) for p in probs])
        if n_channels == 1:
            return _split_components(probs[0] > self.threshold, self.min_area_px)
        if self.layout == "instances":
            return [m for m in (p > self.threshold for p in probs)
                    if np.count_nonzero(m) >= self.min_area_px]
        winner = np.argmax(probs, axis=0)
        return [c for cls in range(1, n_channels)
                for c in _split_components(winner == cls, self.min_area_px)]


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (0.5 * (1.0 + np.tanh(0.5 * x))).astype(np.float32)  # overflow-free logistic


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(axis=0, keepdims=True))
    return (e / e.sum(axis=0, keepdims=True)).astype(np.float32)
