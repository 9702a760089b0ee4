"""The built-in mask stage: textureless regions around cross-view-consistent highlights.

Needs no training data: it grows a textureless region around each specular highlight of
the reference view and keeps it only if every other view shows the same highlight where
a single 3D point would put it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from skimage.segmentation import watershed

from .._checks import check_views
from ..errors import SRDEError
from ..geometry import CameraRig, robust_triangulate
from ..imaging import luminance, saturation_mask, to_float
from ..srde import components, weighted_centroid

__all__ = [
    "HighlightSegmenter",
    "SegmenterDiagnostics",
]

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
        # The blob detector's primitives: 8-connected components, luminance-weighted centres.
        lum = luminance(image, encoding)
        bright = (lum >= self.seed_luminance) | saturation_mask(image)
        n, comp, stats = components(bright)
        blobs = []
        for i in range(1, n):  # a handful of blobs, not pixels
            area = int(stats[i, cv2.CC_STAT_AREA])
            if area < self.min_seed_area_px:
                continue
            x, y, w, h = (int(s) for s in stats[i, :4])
            mask = comp == i
            box = (slice(y, y + h), slice(x, x + w))
            center = weighted_centroid(np.where(mask[box], lum[box], 0.0).astype(np.float64))
            blobs.append(_Blob(center + np.array([x, y], dtype=np.float64), area, mask))
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
        """Find the highlight's common inverse depth across views, or why there is none.

        Each blob of another view proposes the inverse depth ``w`` the seed's 3D point
        would have if that blob were its image (the shift ``c_ref - c_j = a_j w`` with
        ``a_j = (fx dX_j, fy dY_j)``). For each proposal the blob nearest to where ``w``
        puts the point is taken in every view, and
        :func:`~srde_fusion.geometry.robust_triangulate` keeps the views that agree on one
        point; the proposal with the most agreeing views wins.
        """
        k = rig.intrinsics
        ref = rig.reference
        tol = max(self.consistency_tol_px,
                  self.consistency_tol_rel * float(np.sqrt(blob.area_px / np.pi)))
        offsets = {j: np.array([k.fx * d[0], k.fy * d[1]])
                   for j, d in ((j, rig.centers_m[j] - rig.reference_center_m)
                                for j in blobs_per_view)}
        proposals = sorted({max(float(s @ a / (a @ a)), 0.0)
                            for j, a in offsets.items()
                            for s in (blob.center_uv - b.center_uv for b in blobs_per_view[j])
                            if float(s @ a / (a @ a)) > -tol / np.linalg.norm(a)})
        n_needed = (len(blobs_per_view) if self.min_consistent_views is None
                    else min(self.min_consistent_views, len(blobs_per_view)))
        best_w, best_views = np.nan, set()
        for w in proposals:
            centers = np.full((rig.n_cameras, 2), np.nan)
            centers[ref] = blob.center_uv
            for j, blobs in blobs_per_view.items():
                predicted = blob.center_uv - offsets[j] * w
                gaps = [float(np.linalg.norm(b.center_uv - predicted)) for b in blobs]
                if gaps and min(gaps) <= tol:
                    centers[j] = blobs[int(np.argmin(gaps))].center_uv
            tri = robust_triangulate(rig, centers, max_residual_px=tol)
            agree = {j for j in blobs_per_view if tri.used[j]} if tri.used[ref] else set()
            if len(agree) > len(best_views):
                best_w, best_views = tri.inverse_depth_per_m, agree
        if len(best_views) >= n_needed:
            return best_w, ""
        missing = sorted(set(blobs_per_view) - best_views)
        return np.nan, (f"views {missing} show no highlight where the reference highlight's 3D "
                        f"point would appear ({len(best_views)} of {n_needed} views agree "
                        f"within {tol:.1f} px)")


def _component_with(passable: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Return the 8-connected components of ``passable`` that touch ``seed``."""
    labels, _ = ndimage.label(passable, structure=np.ones((3, 3), bool))
    ids = np.unique(labels[seed])
    return np.isin(labels, ids[ids > 0])
