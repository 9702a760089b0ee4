"""SRDE: the disparity of a flat glossy object from its specular highlight.

A planar glossy surface mirrors the light L; every camera sees the highlight as the
image of the same virtual light V, L's mirror image across the plane. Triangulating V
from the highlight centres and knowing L fixes the plane (normal along V - L, through
(V + L) / 2), and casting the reference camera's pixel rays onto it gives the disparity
of every pixel of the object (Kossira et al., Methods).

Two methods:

``method="default"``
    Sub-pixel blob centres on linear intensity; one least-squares triangulation of V
    from all views (linear in the reference image of V and its inverse depth, residuals
    in pixels); views whose centre does not fit one 3D point are dropped and named.
    The plane is then refined photometrically (:func:`~srde_fusion.srde.refine.plane.refine_plane`:
    a lobe model fitted to the highlights of all views removes the centroid bias of
    rough surfaces); if the refinement fails, the geometric plane is kept and a note says
    why. Works on any rectified rig of two or more cameras.
``method="paper"``
    The paper as published: edge-ring centroids; V triangulated separately for every
    pair of neighbouring cameras; one disparity map per pair; their pixel-wise median.
    Kept as the baseline.

Both search for the highlight only inside the object's eroded mask in the reference
view, and in every other view only where the reference highlight can appear: along the
camera's baseline, over the plausible depth range of V, within the reference blob's
size. What cannot be trusted is reported, never raised: the result's
``status`` and ``reason`` say which step failed, in which view, with which numbers.
"""

from __future__ import annotations

import math
import warnings

import cv2
import numpy as np

from .._checks import Views, check_mask, check_views
from ..boxes import eroded
from ..errors import LightError, RigError, SRDEError
from ..geometry import (
    CameraRig,
    adjacent_pairs,
    incidence_angle_deg,
    max_shift_px,
    pairwise_virtual_lights,
    plane_disparity,
    plane_from_lights,
    robust_triangulate,
    triangulate_rectified,
)
from .backends import DetectionRequest, HighlightBackend, NumpyBackend
from .candidates import gather_candidates
from .config import DEFAULT_BLOB_CENTER, MIN_BLOB_AREA_PX, DetectorConfig
from .faces import MAX_FACES, estimate_faces
from .highlight import HighlightDetection, search_box
from .lights import check_lights, estimate_with_lights
from .refine import DEFAULT_LOBE, LOBES, refine_plane
from .refine.radius import RADIUS_NOTE, RadiusFit, refine_plane_and_radius
from .result import SRDEResult
from .search import BaselineSearch

__all__ = [
    "SRDE",
    "SRDE_METHODS",
]

#: Methods accepted by :class:`SRDE`.
SRDE_METHODS = ("default", "paper")


# The virtual light's image must move at least this much across the used views (pixels)
# for its depth to mean anything; below, V is "at infinity".
MIN_VIRTUAL_LIGHT_SHIFT_PX = 1.0


# |V - L| below this fraction of the light's distance from the reference camera means the
# light lies (nearly) on the plane; the normal direction V - L is then mostly noise.
LIGHT_ON_PLANE_FRACTION = 0.01


# The grazing check trusts a box whose corner rays are at least this far (degrees) below
# max_incidence_deg; the angles' rounding is some 1e-12 deg.
GRAZING_CHECK_MARGIN_DEG = 1e-6


# A light farther than this (metres, per coordinate; the sun is 1.5e11 m away) is a
# placeholder or a unit slip: its virtual light is at infinity for any rig, and far enough
# out its squared distances overflow.
MAX_LIGHT_DISTANCE_M = 1e12


def _number(value, name: str, *, low: float = 0.0, low_open: bool = True,
            high: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        raise SRDEError(f"{name}: expected a number, got {value!r}")
    value = float(value)
    bad_low = value <= low if low_open else value < low
    if math.isnan(value) or bad_low or value > high:
        bracket = "(" if low_open else "["
        raise SRDEError(f"{name}: expected a number in {bracket}{low:g}, {high:g}], got {value!r}")
    return value


class SRDE:
    """Estimate the plane and disparity of a flat glossy object from its highlight.

    Parameters
    ----------
    rig : CameraRig
        The rectified rig the views come from.
    light : array_like, (3,), optional
        The point light in the array frame, metres; by default the rig's light(s),
        whose ``radius_m`` (where ``rig.json`` gives one) the photometric refinement
        then models as the extent of a spherical light. A light given here is a point.
    method : {"default", "paper"}
        See the module docstring.
    detector : {"blob", "paper"}, optional
        Override the highlight detector of the method (``"blob"`` for default, ``"paper"``
        for paper), e.g. to measure what each part contributes.
    window, k, min_extent_px : int, float, int
        The paper detector's window side (px), threshold factor and minimum component
        extent (px); see :func:`~srde_fusion.srde.highlight.detect_highlight`.
    blob_center : {"weighted", "core", "lobe"}
        The blob detector's sub-pixel centre estimator.
    min_contrast : float
        The blob detector's minimum peak contrast over the object (linear intensity).
    mask_erosion_px : int
        The object mask is eroded by this radius before the reference view is searched,
        so its border (and the edges it makes) stay out of the search.
    max_residual_px, min_residual_px : float
        Outlier bounds of the default method, pixels: a view whose centre misses the
        triangulated virtual light by more than ``max_residual_px`` is dropped; with
        five or more agreeing views the bound tightens to four robust standard
        deviations of their residuals, but not below ``min_residual_px`` (see
        :func:`~srde_fusion.geometry.triangulation.robust_triangulate`).
    min_views : int
        Fewest agreeing views for an ``ok`` result (at least 2).
    object_depth_m : (float, float)
        Plausible depth range (reference camera z, metres) of the object. With the
        light's position it bounds the depth of the virtual light seen along the
        reference highlight's ray, which sets how far along each baseline the other
        views are searched.
    max_incidence_deg : float
        A plane that some mask pixel ray meets at more than this angle from its normal
        is "grazing": depth there is ill-conditioned.
    white_references : sequence of N images, optional
        Images of a white reference target, one per camera (same size and encoding as
        the views). Each view's linear intensity is divided by its camera's smoothed
        white image before detection (the paper normalises with reflection standards).
    refine : bool, optional
        Refine the plane photometrically (:func:`~srde_fusion.srde.refine_plane`) after
        triangulation; by default on for ``method="default"``, off for ``"paper"``
        (which stays the paper's). Only the default method's joint solve is refined.
    refine_lobe : {"gtr", "ggx", "blinn_phong"}
        Lobe model of the refinement (see :data:`~srde_fusion.srde.refine.LOBES`).
    refine_pixels : bool, optional
        The refinement fits every pixel near the highlights (True) or the means of small
        blocks of them (False). By default every pixel on a rig of two cameras (more
        accurate there, at several times the time: ``refine_pixels=False`` is the fast
        choice), blocks on larger arrays (see
        :func:`~srde_fusion.srde.refine_plane`'s ``pixel_samples``).
    backend : {"numpy", "torch"} or HighlightBackend
        Where the pixel work of detection runs: numpy and OpenCV on the host (default),
        or torch, batched over the views, on ``device`` (see
        :class:`~srde_fusion.srde.BatchedSRDE`). Results agree to about 1e-5 px.
    device : str or torch.device, optional
        The torch backend's device (``"cpu"``, ``"cuda"``, ``"cuda:1"``, ...).
    max_faces : int
        Up to this many flat faces per object (1-3; default 1, one plane). With 2 or 3,
        an object whose highlights show several planes is split into faces, each with
        its plane (:mod:`~srde_fusion.srde.faces`); one that shows a single plane takes
        the usual path. Needs ``method="default"`` and the numpy backend.

    Raises
    ------
    RigError
        ``rig`` is not a CameraRig.
    LightError
        No light given and the rig has none, or the light is not 3 finite numbers.
    ImageError
        ``white_references`` are not N images of the rig's size.
    SRDEError
        An option is out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion.geometry.rig import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=400.0, image_size=(96, 64))
    >>> srde = SRDE(rig, light=[0.05, -0.3, 0.2])
    >>> result = srde.estimate([np.zeros((64, 96), np.uint8)] * 2, np.ones((64, 96), bool))
    >>> result.status, result.reason.split(":")[0]
    ('no_highlight', 'view 0 (left, reference)')
    """

    def __init__(self, rig: CameraRig, light=None, *, method: str = "default",
                 detector: str | None = None, window: int = 15, k: float = 1.5,
                 min_extent_px: int = 10, blob_center: str = DEFAULT_BLOB_CENTER,
                 min_contrast: float = 0.05, mask_erosion_px: int = 3,
                 max_residual_px: float = 1.0, min_residual_px: float = 0.05,
                 min_views: int = 2,
                 object_depth_m: tuple[float, float] = (0.2, 10.0),
                 max_incidence_deg: float = 85.0, white_references=None,
                 refine: bool | None = None, refine_lobe: str = DEFAULT_LOBE,
                 refine_pixels: bool | None = None,
                 backend: str | HighlightBackend = "numpy", device=None,
                 max_faces: int = 1) -> None:
        if not isinstance(rig, CameraRig):
            raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
        if method not in SRDE_METHODS:
            raise SRDEError(f"method: expected one of {list(SRDE_METHODS)}, got {method!r}")
        if detector is None:
            detector = "paper" if method == "paper" else "blob"
        config = DetectorConfig(method=detector, encoding=rig.image_encoding, window=window, k=k,
                                min_extent_px=min_extent_px, blob_center=blob_center,
                                min_contrast=min_contrast, min_area_px=MIN_BLOB_AREA_PX)
        radii_m: tuple[float | None, ...] | None = None  # unknown for a light given here
        if light is None:
            light = rig.light_positions_m
            radii_m = tuple(entry.radius_m for entry in rig.lights)
            if len(light) == 0:
                raise LightError("light: expected a light position (x, y, z) in metres, or a rig "
                                 "with a light, got neither")
        lights_m = check_lights(light)
        light_m = lights_m[0]
        reach_m = float(np.max(np.abs(lights_m - rig.reference_center_m)))
        if reach_m > MAX_LIGHT_DISTANCE_M:
            raise LightError(f"light: expected a position within {MAX_LIGHT_DISTANCE_M:g} m of the "
                             f"reference camera, got one {reach_m:.3g} m away")
        if len(lights_m) > 1 and (method != "default" or backend != "numpy"):
            raise SRDEError(f"light: several lights need method='default' and backend='numpy', "
                            f"got method={method!r}, backend={backend!r}")
        if (isinstance(max_faces, bool) or not isinstance(max_faces, (int, np.integer))
                or not 1 <= max_faces <= MAX_FACES):
            raise SRDEError(f"max_faces: expected an integer in [1, {MAX_FACES}], got "
                            f"{max_faces!r}")
        if max_faces > 1 and (method != "default" or backend != "numpy"):
            raise SRDEError(f"max_faces: faces need method='default' and backend='numpy', got "
                            f"method={method!r}, backend={backend!r}")
        if (isinstance(mask_erosion_px, bool) or not isinstance(mask_erosion_px, (int, np.integer))
                or mask_erosion_px < 0):
            raise SRDEError(f"mask_erosion_px: expected an integer >= 0 (pixels), got "
                            f"{mask_erosion_px!r}")
        if (isinstance(min_views, bool) or not isinstance(min_views, (int, np.integer))
                or not 2 <= min_views <= rig.n_cameras):
            raise SRDEError(f"min_views: expected an integer in [2, {rig.n_cameras}] (the rig's "
                            f"cameras), got {min_views!r}")
        self.max_residual_px = _number(max_residual_px, "max_residual_px")
        self.min_residual_px = _number(min_residual_px, "min_residual_px",
                                       high=self.max_residual_px)
        self.max_incidence_deg = _number(max_incidence_deg, "max_incidence_deg", high=90.0)
        try:
            z_near, z_far = (float(z) for z in object_depth_m)
        except (TypeError, ValueError):
            raise SRDEError(f"object_depth_m: expected (near, far) in metres, got "
                            f"{object_depth_m!r}") from None
        if not (0.0 < z_near < z_far < math.inf):
            raise SRDEError(f"object_depth_m: expected 0 < near < far < inf (metres), got "
                            f"{object_depth_m!r}")
        if refine is not None and not isinstance(refine, bool):
            raise SRDEError(f"refine: expected True, False or None, got {refine!r}")
        if refine_lobe not in LOBES:
            raise SRDEError(f"refine_lobe: expected one of {list(LOBES)}, got {refine_lobe!r}")
        if refine_pixels is not None and not isinstance(refine_pixels, bool):
            raise SRDEError(f"refine_pixels: expected True, False or None, got "
                            f"{refine_pixels!r}")
        self.rig = rig
        self.light_m = light_m
        self.lights_m = lights_m
        self.light_radii_m = radii_m if radii_m is not None else (None,) * len(lights_m)
        self.method = method
        # The paper's method stays the paper's unless asked otherwise.
        self.refine = (method == "default") if refine is None else refine
        self.refine_lobe = refine_lobe
        self.refine_pixels = refine_pixels
        self.config = config
        self.mask_erosion_px = int(mask_erosion_px)
        self.min_views = int(min_views)
        self.max_faces = int(max_faces)
        self.object_depth_m = (z_near, z_far)
        whites = None
        if white_references is not None:
            refs = check_views(white_references, rig.n_cameras, rig.image_size)
            whites = Views(r.copy() for r in refs)
        self.backend = _make_backend(backend, rig, config, whites, device)
        self.search = BaselineSearch(rig, light_m, self.object_depth_m, detector == "paper")

    @property
    def detector(self) -> str:
        """The highlight detector, ``"blob"`` or ``"paper"``."""
        return self.config.method

    # ------------------------------------------------------------------ public
    def estimate(self, views, mask, *, region=None) -> SRDEResult:
        """Estimate the object's plane and disparity from the rig's views.

        Parameters
        ----------
        views : sequence of N images, (H, W) or (H, W, 3), uint8 or float32 in [0, 1]
            One image per camera, in the rig's order.
        mask : numpy.ndarray, (H, W) bool
            The object's mask in the reference view.
        region : numpy.ndarray, (H, W) bool, optional
            Where to search for the highlight in the reference view, instead of the
            eroded mask. The disparity still covers the whole mask.

        Returns
        -------
        SRDEResult
            ``status == "ok"`` with the disparity inside the mask, or a failure code and
            a reason (never an exception for geometric failures).

        Raises
        ------
        ImageError
            Wrong number of views, sizes that differ from the rig's, bad dtype or values.
        MaskError
            ``mask`` (or ``region``) has the wrong shape or dtype, or is empty.
        """
        return self._estimate(self.backend.prepare(views), mask, region)

    # ------------------------------------------------------------------ steps
    def _estimate(self, views, mask, region) -> SRDEResult:
        """:meth:`estimate` on validated views (in whatever form the detection steps take)."""
        rig = self.rig
        shape = (rig.height, rig.width)
        mask = check_mask(mask, shape)
        if region is not None:
            search = check_mask(region, shape, "region")
        else:
            search = self._erode(mask)
            if not search.any():
                return self._failed(
                    "mask_too_small", f"mask: nothing left to search after eroding the "
                    f"{int(mask.sum())}-px mask by {self.mask_erosion_px} px")
        if self.max_faces == 1:
            return self._one_plane(views, mask, search, None)
        gathered = gather_candidates(self, views, search)  # found once for faces and lights
        faceted = estimate_faces(self, views, mask, gathered)
        if faceted is None:
            return self._one_plane(views, mask, search, gathered)
        if faceted.ok:
            return faceted
        # Sets of faces were tried and every one failed. A flat object whose blobs suggest
        # a second plane (a highlight of another light on its flank, say) is still the
        # one-plane path's to solve, by that path's own checks; a faceted object it
        # refuses (it solved none of the faceted benchmark's 600 objects), and the faces'
        # reason stands.
        one_plane = self._one_plane(views, mask, search, gathered, faces_tried=True)
        return one_plane if one_plane.ok else faceted

    def _one_plane(self, views, mask, search, gathered, *, faces_tried: bool = False
                   ) -> SRDEResult:
        """Estimate the object as one plane: by several lights or by the single light.

        ``gathered``: every view's candidates when the faces' step found them (None
        otherwise). ``faces_tried``: the faces' tries all failed already; none is made
        again.
        """
        rig = self.rig
        if len(self.lights_m) > 1:
            result = estimate_with_lights(self, views, mask, search, gathered=gathered)
            if self.max_faces == 1 or faces_tried or result.status not in (
                    "inconsistent", "ambiguous", "too_few_views"):
                return result
            # No face split was found, and the highlights hold evidence against one plane
            # or two planes explain them alike: faces from every view's candidates
            # (faces.estimate_faces), or this failure. (Objects without such evidence,
            # a highlight missing say, are not tried again: the try costs tens of ms.)
            # When no plane explains the centres at all, only blobs cut by a straight
            # edge (centred on their arcs) can change that.
            again = estimate_faces(self, views, mask, gathered, every_view=True,
                                   cut_only=result.status == "too_few_views")
            return result if again is None else again
        ref = rig.reference
        search_bbox = search_box(search, 0)
        if search_bbox is None:  # an empty region: the detector says so
            ref_det = self.backend.detect(views, [DetectionRequest(ref, search)])[0]
        else:
            ref_det = self.backend.detect(views, [DetectionRequest(ref, search, None,
                                                                   search_bbox)])[0]
        if not ref_det:
            if self.method == "default" and isinstance(self.backend, NumpyBackend):
                # An object may turn the highlight away from the reference camera alone:
                # the views that see it give the plane, anchored in them as several
                # lights' highlights are (one light is a list of one). Only a plane
                # replaces this refusal.
                anchored = estimate_with_lights(self, views, mask, search)
                if anchored.ok:
                    return anchored
            return self._failed("no_highlight", f"{self._view(ref)}: {ref_det.reason}",
                                detections=(ref_det,))
        detections = self._detect_others(views, ref_det, search, search_bbox)
        centers = np.full((rig.n_cameras, 2), np.nan)
        for j, det in enumerate(detections):
            if det:
                centers[j] = det.center_uv
        found = np.all(np.isfinite(centers), axis=1)
        missing = [f"{self._view(j)}: {detections[j].reason}" for j in np.flatnonzero(~found)]
        if found.sum() < self.min_views:
            return self._failed(
                "no_highlight", f"only {int(found.sum())} of {rig.n_cameras} views show a "
                f"highlight (min_views {self.min_views}); " + "; ".join(missing),
                centers=centers, detections=tuple(detections))
        if self.method == "paper":
            return self._solve_paper(mask, centers, tuple(detections), missing)
        return self._solve_joint(views, mask, centers, tuple(detections), missing)

    def _view(self, j: int) -> str:
        ref = ", reference" if j == self.rig.reference else ""
        return f"view {j} ({self.rig.cameras[j].name}{ref})"

    def _erode(self, mask: np.ndarray) -> np.ndarray:
        r = self.mask_erosion_px
        if r == 0:
            return mask
        return eroded(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))

    def _detect_others(self, views, ref_det: HighlightDetection, search: np.ndarray,
                       search_bbox: tuple[int, int, int, int]) -> list[HighlightDetection]:
        """Every view's detection: the reference's as given, the others where it can appear.

        ``search_bbox`` is the bounding box ``(u0, v0, u1, v1)`` of ``search``.
        """
        rig = self.rig
        others = [j for j in range(rig.n_cameras) if j != rig.reference]
        candidates = self.search.all_candidates(others, ref_det, search)
        reachable = [(j, c) for j, c in candidates.items() if c is not None]
        regions = {}
        if reachable:
            best = self.backend.brightest(views, reachable)
            regions = {j: self.search.boxed_region_at(c, b, search, search_bbox)
                       for (j, c), b in zip(reachable, best, strict=True)}
        # One level for all views: an asymmetric lobe's centroid depends on it.
        level = None if np.isnan(ref_det.level) else ref_det.level
        requests = [DetectionRequest(j, r, level, bbox) for j, (r, bbox) in regions.items()
                    if bbox is not None]
        found = dict(zip([r.view for r in requests], self.backend.detect(views, requests),
                         strict=True))
        return [ref_det if j == rig.reference
                else found[j] if j in found else self.search.off_object()
                for j in range(rig.n_cameras)]

    def _solve_joint(self, views, mask, centers, detections, missing) -> SRDEResult:
        rig = self.rig
        tri = robust_triangulate(rig, centers, max_residual_px=self.max_residual_px,
                                 min_residual_px=self.min_residual_px)
        found = np.all(np.isfinite(centers), axis=1)
        if not tri.used.any():
            plain = triangulate_rectified(rig, centers)
            res = ", ".join(f"{j}: {plain.residuals_px[j]:.2f}" for j in np.flatnonzero(found))
            return self._failed(
                "inconsistent", f"triangulation: no two views agree on one virtual light within "
                f"{self.max_residual_px:g} px; residuals of a joint fit per view (px) {{{res}}}",
                centers=centers, detections=detections)
        dropped = [f"{self._view(j)}: dropped as an outlier, {tri.residuals_px[j]:.2f} px from the "
                   f"virtual light the other views agree on"
                   for j in np.flatnonzero(found & ~tri.used)]
        notes = tuple(missing) + tuple(dropped)
        if tri.used.sum() < self.min_views:
            return self._failed(
                "too_few_views", f"triangulation: only {int(tri.used.sum())} views agree "
                f"(min_views {self.min_views}); " + "; ".join(notes),
                centers=centers, used=tri.used, detections=detections)
        return self._finish(mask, tri.point_m, tri.inverse_depth_per_m, tri.used, centers,
                            detections, notes, views=views)

    def _solve_paper(self, mask, centers, detections, missing) -> SRDEResult:
        """Per-pair virtual lights, per-pair disparity maps, pixel-wise median."""
        rig = self.rig
        pairs = adjacent_pairs(rig)
        found = np.all(np.isfinite(centers), axis=1)
        pairs = [p for p in pairs if found[p[0]] and found[p[1]]]
        if not pairs:
            return self._failed(
                "too_few_views", "pairs: no pair of neighbouring cameras has a highlight in "
                "both views; " + "; ".join(missing), centers=centers, detections=detections)
        points = pairwise_virtual_lights(rig, centers, pairs)
        depth = points[:, 2] - rig.reference_center_m[2]
        notes = list(missing)
        keep = []
        for (i, j), point, z in zip(pairs, points, depth, strict=True):
            pair = np.zeros(rig.n_cameras, dtype=bool)
            pair[[i, j]] = True
            shift = max_shift_px(rig, 1.0 / z, pair) if np.isfinite(z) else 0.0
            if shift < MIN_VIRTUAL_LIGHT_SHIFT_PX or z <= 0:
                where = "at infinity" if shift < MIN_VIRTUAL_LIGHT_SHIFT_PX else f"z = {z:.3f} m"
                notes.append(f"pair ({i}, {j}): virtual light {where}, pair dropped")
                continue
            keep.append(((i, j), point))
        if not keep:
            status = "behind_cameras" if np.any(depth[np.isfinite(depth)] < 0) else "at_infinity"
            return self._failed(status, "pairs: every pair's virtual light is behind the cameras "
                                "or at infinity; " + "; ".join(notes[len(missing):]),
                                centers=centers, detections=detections)
        used = np.zeros(rig.n_cameras, dtype=bool)
        for (i, j), _ in keep:
            used[[i, j]] = True
        pair_points = np.stack([p for _, p in keep])
        # The single V reported (and checked) is the component-wise median of the pairs'.
        point = np.median(pair_points, axis=0)
        w = 1.0 / (point[2] - rig.reference_center_m[2])
        result = self._finish(mask, point, w, used, centers, detections, tuple(notes))
        if not result.ok:
            return result
        box, inside = _mask_box(mask)
        planes = [plane_from_lights(self.light_m, p, rig.reference_center_m) for p in pair_points]
        stack = np.stack([plane_disparity(plane, rig, window=box)[inside] for plane in planes])
        with warnings.catch_warnings():  # pixels every pair's plane misses stay NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            median = np.nanmedian(stack, axis=0)
        disparity = _in_box(median, box, inside)
        return SRDEResult("ok", "", disparity, box, mask.shape, result.plane,
                          result.virtual_light_m, centers, used, result.residual_px,
                          self.method, result.notes, detections)

    def _finish(self, mask, point, w, used, centers, detections, notes, *, views=None,
                light=None, refine=None, modelled_lights=(), modelled_centers=None,
                window_centers=None, radius_search=None) -> SRDEResult:
        """Check the virtual light and the plane, refine it (given views); disparity.

        ``light``: the light ``point`` is the virtual light of (one of several); the
        SRDE's light by default. ``refine``: whether to refine; ``self.refine`` by default.
        ``modelled_lights``: further lights whose highlights the refinement renders beside
        ``light``'s (the other lights' are left out of its windows); ``modelled_centers``
        ``(M, N, 2)``: their highlights, which the refinement's windows go around too.
        ``window_centers`` ``(N, 2)``: where the refinement's windows go around ``light``'s
        highlight (NaN: no window in that view); the used ``centers`` by default.
        ``radius_search``: a dict (possibly empty) of options of
        :func:`~.refine.radius.refine_plane_and_radius`: if the rig does not know
        ``light``'s radius, the refinement fits it too with them; None (the default) or
        a known radius: the radius is not fitted (a known one is used as is).
        """
        rig = self.rig
        fail = {"centers": centers, "used": used, "detections": detections}
        shift = max_shift_px(rig, w, used) if np.isfinite(w) else 0.0
        if shift < MIN_VIRTUAL_LIGHT_SHIFT_PX:
            return self._failed(
                "at_infinity", f"virtual light: its image moves only {shift:.3f} px across the "
                f"used views (needs {MIN_VIRTUAL_LIGHT_SHIFT_PX:g} px); it is at infinity", **fail)
        if w < 0:
            return self._failed(
                "behind_cameras", f"virtual light: triangulated at z = {1.0 / w:.3f} m, behind "
                f"the cameras (image shift {shift:.2f} px the wrong way)", **fail)
        light = self.light_m if light is None else light
        gap = float(np.linalg.norm(point - light))
        reach = float(np.linalg.norm(light - rig.reference_center_m))
        if gap < LIGHT_ON_PLANE_FRACTION * reach:
            return self._failed(
                "light_on_plane", f"plane: the virtual light is {gap * 1000:.1f} mm from the light "
                f"({gap / reach:.2%} of its {reach:.3f} m distance, limit "
                f"{LIGHT_ON_PLANE_FRACTION:.0%}); the light lies (nearly) on the plane", **fail)
        plane = plane_from_lights(light, point, rig.reference_center_m)
        if plane.signed_distance(light) <= 0:
            return self._failed(
                "light_behind_plane", f"plane: the light is {-plane.signed_distance(light):.3f} m "
                "behind the plane, on the far side from the cameras", **fail)
        behind = np.flatnonzero(used & (plane.signed_distance(rig.centers_m) <= 0))
        if behind.size:
            return self._failed(
                "inconsistent", "plane: the estimated plane leaves "
                + ", ".join(self._view(j) for j in behind)
                + " on its far side, where its highlight cannot be seen", **fail)
        residual = _rms_residual(rig, point, centers, used)
        refinement = None
        if views is not None and (self.refine if refine is None else refine):
            others = [m for m in self.lights_m if not np.array_equal(m, light)
                      and not any(np.array_equal(m, x) for x in modelled_lights)]
            radius_m = next((r for m, r in zip(self.lights_m, self.light_radii_m, strict=True)
                             if np.array_equal(m, light)), None)
            options = dict(centers_uv=(np.where(used[:, None], centers, np.nan)
                                       if window_centers is None else window_centers),
                           lobe=self.refine_lobe,
                           other_lights_m=np.array(others) if others else None,
                           modelled_lights_m=(np.array(modelled_lights)
                                              if len(modelled_lights) else None),
                           modelled_centers_uv=modelled_centers,
                           pixel_samples=self.refine_pixels)
            if radius_search is not None and radius_m is None:
                search = refine_plane_and_radius(views, rig, light, mask, plane,
                                                 **radius_search, **options)
                refinement = search.refinement
                if refinement.ok:
                    notes = (*notes, _radius_note(search))
            else:
                refinement = refine_plane(views, rig, light, mask, plane,
                                          light_radius_m=radius_m, **options)
            if refinement.ok:
                plane = refinement.plane
                point = plane.mirror(light)
            else:
                notes = (*notes, f"refinement: kept the geometric plane; {refinement.reason}")
        # Rays of the mask's bounding box are separable; a ray per mask pixel costs more.
        box, inside = _mask_box(mask)
        if self._grazing_possible(plane, box):
            angle = incidence_angle_deg(plane, rig, window=box)[inside]
            steep = angle > self.max_incidence_deg
        else:
            steep = np.zeros(0, dtype=bool)
        if steep.any():
            worst = int(np.argmax(angle))
            uv = _mask_uv(mask)
            return self._failed(
                "grazing", f"plane: {int(steep.sum())} of {uv.shape[0]} mask pixels see it at more "
                f"than {self.max_incidence_deg:g} deg incidence (worst {angle[worst]:.1f} deg at "
                f"pixel ({uv[worst, 0]:.0f}, {uv[worst, 1]:.0f}))", plane=plane, point=point,
                **fail)
        disparity = _plane_disparity_in_box(plane, rig, box, inside)
        return SRDEResult("ok", "", disparity, box, mask.shape, plane,
                          np.asarray(point, dtype=np.float64),
                          centers, used, residual, self.method, tuple(notes), detections,
                          refinement)

    def _finish_on_plane(self, mask, plane, light, used, centers, detections, notes,
                         **options) -> SRDEResult:
        """:meth:`_finish` for the virtual light ``plane`` mirrors ``light`` to.

        For a plane already known (a face's, a lobe fit's); ``options`` go to ``_finish``.
        """
        point = plane.mirror(light)
        w = 1.0 / (point[2] - self.rig.reference_center_m[2])
        return self._finish(mask, point, w, used, centers, detections, notes, light=light,
                            **options)

    def _grazing_possible(self, plane, box) -> bool:
        """Whether any pixel of the box ``(u0, v0, u1, v1)`` may see the plane too obliquely.

        Rays within an angle below 90 deg of a direction form a convex cone, which meets
        the image plane in a convex set: if the box's corner pixels lie in it, so does
        every pixel of the box. The corners are checked with a margin far above the
        angles' rounding, so a False here is exact; True asks for the per-pixel check.
        """
        if self.max_incidence_deg >= 90.0 - GRAZING_CHECK_MARGIN_DEG:
            return True
        u0, v0, u1, v1 = box
        corners = np.array([[u0, v0], [u1 - 1, v0], [u0, v1 - 1], [u1 - 1, v1 - 1]],
                           dtype=np.float64)
        angle = incidence_angle_deg(plane, self.rig, corners)
        return not bool(np.all(angle <= self.max_incidence_deg - GRAZING_CHECK_MARGIN_DEG))

    def _failed(self, status: str, reason: str, *, centers=None, used=None, detections=(),
                plane=None, point=None) -> SRDEResult:
        rig = self.rig
        n = rig.n_cameras
        residual = float("nan")
        if centers is not None and used is not None and point is not None:
            residual = _rms_residual(rig, point, centers, used)
        return SRDEResult(
            status, reason, np.zeros((0, 0), dtype=np.float32), (0, 0, 0, 0),
            (rig.height, rig.width), plane,
            None if point is None else np.asarray(point, dtype=np.float64),
            np.full((n, 2), np.nan) if centers is None else centers,
            np.zeros(n, dtype=bool) if used is None else used, residual, self.method, (),
            tuple(detections))


def _mask_box(mask: np.ndarray) -> tuple[tuple[int, int, int, int], np.ndarray]:
    """Return the mask's bounding box ``(u0, v0, u1, v1)`` and the mask cropped to it."""
    u0, v0, u1, v1 = search_box(mask, 0)
    return (u0, v0, u1, v1), mask[v0:v1, u0:u1]


def _in_box(values: np.ndarray, box, inside: np.ndarray) -> np.ndarray:
    """Return the box's float32 map, NaN except ``values`` at its ``inside`` pixels."""
    u0, v0, u1, v1 = box
    out = np.full((v1 - v0, u1 - u0), np.nan, dtype=np.float32)
    out[inside] = values
    return out


def _plane_disparity_in_box(plane, rig, box, inside: np.ndarray) -> np.ndarray:
    """``_in_box(plane_disparity(plane, rig, window=box)[inside], box, inside)``, in fewer passes.

    The same arithmetic as :func:`~srde_fusion.geometry.plane.plane_depth` and
    ``CameraRig.depth_to_disparity`` (``z = num / denom``, ``fx B / z`` where
    ``0 < z < inf``), with the mask applied in the same pass instead of a gather and a
    scatter: the same float32 values, NaN elsewhere.
    """
    u0, v0, u1, v1 = box
    k = rig.intrinsics
    n = plane.n
    num = plane.offset_m - float(np.dot(n, rig.reference_center_m))
    x = (np.arange(u0, u1, dtype=np.float64) - k.cx) / k.fx
    y = (np.arange(v0, v1, dtype=np.float64) - k.cy) / k.fy
    denom = n[0] * x[None, :] + n[1] * y[:, None] + n[2]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        z = num / denom
        disparity = k.fx * rig.baseline_m / z
    keep = (z > 0) & (z < np.inf) & inside
    return np.where(keep, disparity, np.nan).astype(np.float32)


def _mask_uv(mask: np.ndarray) -> np.ndarray:
    """Pixel coordinates ``(u, v)`` of the mask's pixels in row-major order, ``(M, 2)``."""
    vv, uu = np.nonzero(mask)
    return np.stack([uu, vv], axis=1).astype(np.float64)


def _radius_note(search: RadiusFit) -> str:
    """Say which radius the refinement took for a light the rig gives none, and why."""
    point = (f"as a point {search.point_cost:.3g}" if math.isfinite(search.point_cost)
             else "a point light's fit was refused")
    if search.light_radius_m > 0.0:
        return (f"{RADIUS_NOTE}; fitted {search.light_radius_m * 1000:.1f} mm (photometric "
                f"cost {search.refinement.cost_final:.3g}, {point})")
    if search.cheapest_radius_m == 0.0:
        return (f"{RADIUS_NOTE}; kept a point light (every radius tried cost more; "
                f"photometric cost {search.point_cost:.3g})")
    return (f"{RADIUS_NOTE}; kept a point light (the cheapest radius, "
            f"{search.cheapest_radius_m * 1000:.1f} mm, saved {search.saving:.1%} of the point "
            f"light's photometric cost {search.point_cost:.3g}; {search.min_gain:.0%} needed)")


def _rms_residual(rig, point, centers, used) -> float:
    # rig.project's arithmetic for every camera at once.
    rel = np.asarray(point, dtype=np.float64) - rig.centers_m                       # (N, 3)
    k = rig.intrinsics
    z = rel[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(z > 0, k.fx * rel[:, 0] / z + k.cx, np.nan)
        v = np.where(z > 0, k.fy * rel[:, 1] / z + k.cy, np.nan)
    pred = np.stack([u, v], axis=-1)
    err = np.linalg.norm(pred - centers, axis=1)[used]
    return float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan")


def _make_backend(backend, rig: CameraRig, config: DetectorConfig, whites: Views | None,
                  device) -> HighlightBackend:
    """Build the detector backend ``SRDE(backend=...)`` names, or check a given one."""
    if backend == "numpy":
        if device is not None and str(device) != "cpu":
            raise SRDEError(f"device: expected None or 'cpu' for the numpy backend, got "
                            f"{device!r} (use backend='torch' for another device)")
        return NumpyBackend(rig, config, whites)
    if backend == "torch":
        # torch is imported only when the torch backend is asked for.
        from .torch_backend import TorchBackend

        return TorchBackend(rig, config, whites, device="cpu" if device is None else device)
    if isinstance(backend, str) or not all(
            callable(getattr(backend, name, None)) for name in ("prepare", "detect", "brightest")):
        raise SRDEError(f"backend: expected 'numpy', 'torch' or an object with prepare, detect "
                        f"and brightest methods, got {backend!r}")
    return backend
