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

from ._checks import check_views
from .errors import BackboneError, FileFormatError, MaskError
from .imaging import REC709_LUMA, luminance, saturation_mask, to_float
from .io import masks_from_labels, read_mask
from .rig import CameraRig

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


class HighlightSegmenter:
    """Built-in mask stage: textureless regions around cross-view-consistent highlights.

    For the reference view:

    1. **Seeds** — bright blobs of linear luminance (at least ``seed_luminance``, or
       clipped) of at least ``min_seed_area_px``.
    2. **Lobe** — the highlight's smooth fall-off around a seed is not an edge of the
       object: the ring-wise median brightness around the seed is followed outwards
       until it stops falling; everything up to there is the lobe.
    3. **Growth** — from the lobe over pixels without a strong edge (Sobel gradient of the
       smoothed luma below ``edge_threshold``), 8-connected; a morphological opening
       cuts thin leaks through gaps in the object's outline, holes are filled, and the
       region is widened by the edge's own width.
    4. **Consistency** — in a rectified array a highlight at ``(u, v)`` in the reference
       view appears in camera ``j`` at ``(u - fx·dX_j/z, v - fy·dY_j/z)`` for the one
       depth ``z > 0`` of its 3D point (the virtual light). The region is kept only if
       every other view has a bright blob at such a place, for a common ``z``.

    Parameters
    ----------
    seed_luminance : float
        Linear luminance in [0, 1] at or above which a pixel can seed a highlight.
    min_seed_area_px : int
        Smallest seed blob, pixels.
    edge_threshold : float
        Gradient magnitude (Sobel 3x3 on Gaussian-smoothed luma in [0, 1]) that counts as
        an object edge or texture.
    smoothing_sigma_px : float
        Gaussian smoothing before the gradient, pixels (suppresses sensor noise).
    opening_radius_px : int
        Radius of the opening that cuts thin leaks.
    min_region_px : int
        Smallest object region, pixels.
    min_region_to_seed : float
        The region must be at least this many times the seed's area (a bright spot in
        texture grows no textureless region around it).
    max_region_fraction : float
        Largest region as a fraction of the image (larger = leaked into the background).
    consistency_tol_px : float
        How far a blob in another view may lie from where the common 3D point puts it.
    min_consistent_views : int or None
        Views (besides the reference) that must agree; all of them by default.

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
                 edge_threshold: float = 0.06, smoothing_sigma_px: float = 1.0,
                 opening_radius_px: int = 2, min_region_px: int = 200,
                 min_region_to_seed: float = 4.0, max_region_fraction: float = 0.6,
                 consistency_tol_px: float = 2.0, min_consistent_views: int | None = None
                 ) -> None:
        if not 0.0 < seed_luminance <= 1.0:
            raise ValueError(f"seed_luminance: expected a value in (0, 1], got {seed_luminance!r}")
        if not 0.0 < max_region_fraction <= 1.0:
            raise ValueError(f"max_region_fraction: expected a value in (0, 1], got "
                             f"{max_region_fraction!r}")
        self.seed_luminance = float(seed_luminance)
        self.min_seed_area_px = int(min_seed_area_px)
        self.edge_threshold = float(edge_threshold)
        self.smoothing_sigma_px = float(smoothing_sigma_px)
        self.opening_radius_px = int(opening_radius_px)
        self.min_region_px = int(min_region_px)
        self.min_region_to_seed = float(min_region_to_seed)
        self.max_region_fraction = float(max_region_fraction)
        self.consistency_tol_px = float(consistency_tol_px)
        self.min_consistent_views = min_consistent_views
        self.last_diagnostics: SegmenterDiagnostics | None = None

    def __call__(self, views: Sequence[np.ndarray], rig: CameraRig) -> list[np.ndarray]:
        """Masks of the glossy objects in the reference view.

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
        """Like calling the segmenter, but also return the per-seed diagnostics."""
        views = check_views(views, rig.n_cameras, rig.image_size)
        ref = views[rig.reference]
        seeds = self._blobs(ref, rig.image_encoding)
        blobs_per_view = {j: self._blobs(views[j], rig.image_encoding)
                          for j in range(rig.n_cameras) if j != rig.reference}
        edges = self._edges(ref)

        masks: list[np.ndarray] = []
        kept, reasons, inv_depths = [], [], []
        h, w = ref.shape[:2]
        for blob in seeds:
            if any(m[int(round(blob.center_uv[1])), int(round(blob.center_uv[0]))] for m in masks):
                kept.append(False)
                reasons.append("inside an object already found")
                inv_depths.append(np.nan)
                continue
            inv_depth, why = self._consistent(blob.center_uv, blobs_per_view, rig)
            if why:
                kept.append(False)
                reasons.append(why)
                inv_depths.append(np.nan)
                continue
            region = self._grow(blob, ref, edges, rig.image_encoding)
            n = int(np.count_nonzero(region))
            why = ""
            if n < self.min_region_px:
                why = f"region of {n} px < min_region_px {self.min_region_px}"
            elif n < self.min_region_to_seed * blob.area_px:
                why = (f"region of {n} px is < {self.min_region_to_seed:g} x the highlight's "
                       f"{blob.area_px} px: no textureless surface around it")
            elif n > self.max_region_fraction * h * w:
                why = (f"region of {n} px covers {n / (h * w):.0%} of the image: the object's "
                       f"outline is not closed")
            kept.append(not why)
            reasons.append(why or f"object of {n} px, highlight at 1/z = {inv_depth:.3f} /m")
            inv_depths.append(inv_depth)
            if not why:
                masks.append(region)
        centers = (np.array([b.center_uv for b in seeds]) if seeds else np.zeros((0, 2)))
        return masks, SegmenterDiagnostics(centers, tuple(kept), tuple(reasons), tuple(inv_depths))

    # ------------------------------------------------------------------ steps
    def _blobs(self, image: np.ndarray, encoding: str) -> list[_Blob]:
        lum = luminance(image, encoding)
        bright = (lum >= self.seed_luminance) | saturation_mask(image)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(bright.astype(np.uint8),
                                                             connectivity=8)
        blobs = []
        for i in range(1, n):
            area = int(stats[i, cv2.CC_STAT_AREA])
            if area < self.min_seed_area_px:
                continue
            mask = comp == i
            weight = lum[mask].astype(np.float64)
            vs, us = np.nonzero(mask)
            center = np.array([np.average(us, weights=weight), np.average(vs, weights=weight)])
            blobs.append(_Blob(center, area, mask))
        return blobs

    def _luma(self, image: np.ndarray) -> np.ndarray:
        gray = to_float(image)
        if gray.ndim == 3:
            gray = gray @ REC709_LUMA
        if self.smoothing_sigma_px > 0:
            gray = cv2.GaussianBlur(gray, (0, 0), self.smoothing_sigma_px)
        return gray

    def _edges(self, image: np.ndarray) -> np.ndarray:
        gray = self._luma(image)
        gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
        return cv2.magnitude(gx, gy) > self.edge_threshold

    def _lobe(self, blob: _Blob, image: np.ndarray) -> np.ndarray:
        """Return the seed plus the smooth fall-off of its highlight around it."""
        gray = self._luma(image)
        dist = ndimage.distance_transform_edt(~blob.mask)
        ring = np.minimum(np.floor(dist), _LOBE_MAX_RADIUS_PX + 1).astype(np.int64)
        sel = ring <= _LOBE_MAX_RADIUS_PX
        # Ring-wise median brightness; the fall-off ends where it stops dropping.
        medians = np.full(_LOBE_MAX_RADIUS_PX + 1, np.nan)
        for r in range(1, _LOBE_MAX_RADIUS_PX + 1):  # a few dozen rings, not pixels
            values = gray[sel & (ring == r)]
            if values.size:
                medians[r] = np.median(values)
        radius = 1
        for r in range(2, _LOBE_MAX_RADIUS_PX + 1):
            if not np.isfinite(medians[r]) or medians[r - 1] - medians[r] < _LOBE_FLAT_STEP:
                break
            radius = r
        return dist <= radius

    def _grow(self, blob: _Blob, image: np.ndarray, edges: np.ndarray, encoding: str
              ) -> np.ndarray:
        lobe = self._lobe(blob, image)
        passable = ~edges | lobe
        labels, _ = ndimage.label(passable, structure=np.ones((3, 3), bool))
        ids = np.unique(labels[blob.mask])
        region = np.isin(labels, ids[ids > 0])
        if self.opening_radius_px > 0:
            disc = cv2.getStructuringElement(
                cv2.MORPH_ELLIPSE, (2 * self.opening_radius_px + 1,) * 2)
            opened = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_OPEN, disc).astype(bool)
            labels, _ = ndimage.label(opened | blob.mask, structure=np.ones((3, 3), bool))
            ids = np.unique(labels[blob.mask])
            region = np.isin(labels, ids[ids > 0])
        region = ndimage.binary_fill_holes(region)
        # The outline's edge pixels belong half to the object: take them back.
        grown = cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        return region | (grown & edges)

    def _consistent(self, center_uv: np.ndarray, blobs_per_view: dict[int, list[_Blob]],
                    rig: CameraRig) -> tuple[float, str]:
        """Find the highlight's common inverse depth across views, or why there is none."""
        k = rig.intrinsics
        ref_c = rig.reference_center_m
        # Per view j, the shift c_ref - c_j equals a_j / z with a_j = (fx dX_j, fy dY_j).
        candidates = []  # (view, inverse depth, a_j, shift)
        for j, blobs in blobs_per_view.items():
            d = rig.centers_m[j] - ref_c
            a = np.array([k.fx * d[0], k.fy * d[1]])
            for b in blobs:
                shift = center_uv - b.center_uv
                inv = float(shift @ a / (a @ a))
                if inv > -self.consistency_tol_px / np.linalg.norm(a):
                    candidates.append((j, max(inv, 0.0), a, shift))
        n_needed = (len(blobs_per_view) if self.min_consistent_views is None
                    else min(self.min_consistent_views, len(blobs_per_view)))
        best_inv, best_views = np.nan, set()
        for _, inv, _, _ in candidates:  # hypotheses: each candidate's depth
            agree = {j for j, _, a, s in candidates
                     if np.linalg.norm(s - a * inv) <= self.consistency_tol_px}
            if len(agree) > len(best_views):
                best_inv, best_views = inv, agree
        if len(best_views) >= n_needed:
            return best_inv, ""
        missing = sorted(set(blobs_per_view) - best_views)
        return np.nan, (f"views {missing} show no highlight where the reference highlight's 3D "
                        f"point would appear ({len(best_views)} of {n_needed} views agree)")


#: How far out (pixels from the seed) the highlight's fall-off is followed.
_LOBE_MAX_RADIUS_PX = 40
#: A ring darker than the previous one by less than this (luma) ends the fall-off.
_LOBE_FLAT_STEP = 0.004


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
            raise ValueError(f"output: expected 'logits' or 'probabilities', got {output!r}")
        if layout not in ("classes", "instances"):
            raise ValueError(f"layout: expected 'classes' or 'instances', got {layout!r}")
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"threshold: expected a probability in (0, 1), got {threshold!r}")
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
