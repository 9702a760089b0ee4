"""Segment planes: a disparity map made planar over colour segments where the images cannot tell.

On a weakly textured surface (a wall's faint pattern, a floor tile between its joints)
every disparity within a pixel or two of the truth matches about equally well: the
census cost there is mostly image noise, and a network's estimate wanders by 0.5-3 px in
blotches that no matching cost can mend. What the images do say is where a surface
begins and ends: colour segments rarely straddle a depth edge, and over a segment a
man-made surface is usually a plane, which in disparity is a plane too
(``d = a + b x + c y`` for a plane in 3D seen by a rectified pair). So:

1. The left image is cut into compact colour segments (SLIC superpixels, about
   :data:`SEGMENT_PX` px across, found at half resolution).
2. Each segment gets a plane fitted robustly to its pixels' disparities (iteratively
   reweighted least squares with a Huber weight, :data:`HUBER_PX`), on every third
   pixel of every third row.
3. A pixel takes its segment's plane only where all three hold:

   - the segment is planar: at least :data:`MIN_INLIER_SHARE` of its pixels lie within
     :data:`INLIER_PX` of the plane;
   - the plane is near the pixel's value, within :data:`REPLACE_PX` (a value farther off
     is another surface: an occluding edge, a thin structure the segment cuts through);
   - the images do not prefer the pixel's own value: the plane's census cost, summed over
     a window, is at most :data:`COST_TOLERANCE_BITS` bits per window pixel above the
     value's own. Both costs are those of a map over the window, each pixel at its own
     value (the plane's there, or the map's), so a slanted plane is judged at its slant.

A non-planar surface (a curved tank, a motorbike's fairing) keeps its values where its
texture tells them apart, and a planar segment only moves values by less than
:data:`REPLACE_PX` where the images are indifferent. A pixel without a value (NaN, inf or
negative) is returned as given and is never part of a fit.

The rule and its constants were chosen on the held-out rendered and procedural pairs
and the real Middlebury pair of the stand-in's record (``training``), after the census
propagation, as its own rules were.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from skimage.segmentation import slic

from .propagation import WINDOW_PX, _bit_counts, _checked, census_pair

__all__ = [
    "COST_TOLERANCE_BITS",
    "HUBER_PX",
    "INLIER_PX",
    "MIN_INLIER_SHARE",
    "REPLACE_PX",
    "SEGMENT_PX",
    "SegmentPlanes",
    "fit_segment_planes",
]

#: Side of a colour segment, px (at full resolution; found at half resolution).
SEGMENT_PX = 32

#: SLIC's balance of colour against position (scikit-image's default scale, 0-100 in Lab).
COMPACTNESS = 10.0

#: SLIC's k-means iterations: three settle segments this size about as well as ten.
SLIC_ITERATIONS = 3

#: Residual below which a pixel has full weight in the plane fit (Huber), px.
HUBER_PX = 0.5

#: Reweighting rounds of the plane fit.
FIT_ITERATIONS = 3

#: A pixel within this distance of its segment's plane is an inlier, px.
INLIER_PX = 1.0

#: A segment is planar when at least this share of its pixels are inliers.
MIN_INLIER_SHARE = 0.5

#: A pixel takes the plane only when its value is within this distance of it, px.
REPLACE_PX = 3.0

#: ... and only when the plane's census cost is at most this many differing bits per
#: window pixel above its own value's.
COST_TOLERANCE_BITS = 1.0

#: Fewest fitted pixels for a segment's plane (of the pixels on the fitting grid).
MIN_FIT_PIXELS = 8

#: ... which must spread at least this far in both directions (standard deviation of
#: their positions, px): a segment one fitted row high does not fix its tilt across.
MIN_SPREAD_PX = 2.0

#: Fit on every this-many-th row and column: against every second, the held-out
#: results moved by well under 1 %; the fit costs a ninth of a full one.
_FIT_STRIDE = 3

#: The segments are found at this fraction of the resolution.
_SEGMENT_SCALE = 2


@dataclass(frozen=True)
class SegmentPlanes:
    """A disparity map after segment planes.

    Attributes
    ----------
    disparity_px : numpy.ndarray, (H, W), float32, pixels
        The map; a pixel without a value (NaN, inf or negative) as given.
    changed_fraction : float
        Share of pixels that took their segment's plane.
    planar_fraction : float
        Share of segments found planar.
    """

    disparity_px: np.ndarray
    changed_fraction: float
    planar_fraction: float


def _segments(image01: np.ndarray) -> np.ndarray:
    """SLIC labels (H, W) int32, 0..n-1, found at ``1 / _SEGMENT_SCALE`` resolution."""
    height, width = image01.shape[:2]
    small = cv2.resize(image01, (max(width // _SEGMENT_SCALE, 1), max(height // _SEGMENT_SCALE, 1)),
                       interpolation=cv2.INTER_AREA)
    side = SEGMENT_PX / _SEGMENT_SCALE
    count = max(int(round(small.shape[0] * small.shape[1] / side**2)), 1)
    labels = slic(small, n_segments=count, compactness=COMPACTNESS,
                  max_num_iter=SLIC_ITERATIONS, start_label=0,
                  channel_axis=-1 if small.ndim == 3 else None)
    return cv2.resize(labels.astype(np.int32), (width, height),
                      interpolation=cv2.INTER_NEAREST)


def _planes(labels: np.ndarray, disparity_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each segment's robust plane and whether it is planar.

    Returns ``(n, 3)`` float64 (a, b, c of ``a + b x + c y``, with x and y from
    :func:`_coordinates`) and ``(n,)`` bool.
    """
    height, width = labels.shape
    count = int(labels.max()) + 1
    rows = slice(None, None, _FIT_STRIDE)
    label = labels[rows, rows].ravel()
    value = disparity_px[rows, rows].ravel().astype(np.float64)
    y, x = (np.broadcast_to(axis, (height, width))[rows, rows].ravel()
            for axis in _coordinates(height, width))
    valued = np.isfinite(value)
    label, value, x, y = label[valued], value[valued], x[valued], y[valued]
    terms = (np.ones_like(value), x, y)
    weight = np.ones_like(value)
    normal = np.empty((count, 3, 3))
    moment = np.empty((count, 3))
    plane = np.zeros((count, 3))
    for _ in range(FIT_ITERATIONS):
        for i in range(3):
            moment[:, i] = np.bincount(label, weight * terms[i] * value, count)
            for j in range(i, 3):
                normal[:, i, j] = normal[:, j, i] = np.bincount(
                    label, weight * terms[i] * terms[j], count)
        # A segment whose fitted pixels lie on a line has a singular system: a small
        # ridge keeps the solve defined (its plane is not trusted: see below).
        plane = np.linalg.solve(normal + 1e-9 * np.eye(3), moment[..., None])[..., 0]
        residual = np.abs(plane[label, 0] + plane[label, 1] * x + plane[label, 2] * y - value)
        weight = 1.0 / np.maximum(residual, HUBER_PX)
    fitted = np.bincount(label, minlength=count)
    inliers = np.bincount(label, (residual < INLIER_PX).astype(np.float64), count)
    share = np.maximum(fitted, 1)
    variance = [np.bincount(label, term**2, count) / share
                - (np.bincount(label, term, count) / share) ** 2 for term in (x, y)]
    planar = ((fitted >= MIN_FIT_PIXELS) & (inliers >= MIN_INLIER_SHARE * share)
              & (np.minimum(*variance) * width**2 >= MIN_SPREAD_PX**2))
    return plane, planar


def _coordinates(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Row ``(H, 1)`` and column ``(1, W)`` coordinates, in image widths about the centre.

    Centred and scaled so that the normal equations of a plane are well conditioned.
    """
    y = (np.arange(height, dtype=np.float64)[:, None] - height / 2) / width
    x = (np.arange(width, dtype=np.float64)[None, :] - width / 2) / width
    return y, x


def _window_costs(census_left: np.ndarray, census_right: np.ndarray,
                  disparity_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Census cost of a map over the window, each pixel at its own rounded value.

    Returns the ``(H, W)`` uint16 window sums and whether every pixel in the window was
    measured (its match inside the right image).
    """
    height, width = disparity_px.shape
    level = np.rint(np.nan_to_num(disparity_px, nan=-1.0, posinf=-1.0, neginf=-1.0))
    column = np.arange(width, dtype=np.float32)[None, :] - level
    inside = (level >= 0) & (column >= 0)
    # The right pixel each left pixel matches, flat; pixel 0 where none (masked below).
    flat = np.where(inside, column + (np.arange(height) * width)[:, None], 0).astype(np.intp)
    distance = _bit_counts(census_left ^ census_right.ravel().take(flat))
    distance[~inside] = 0
    size = (WINDOW_PX, WINDOW_PX)
    cost = cv2.boxFilter(distance, cv2.CV_16U, size, normalize=False,
                         borderType=cv2.BORDER_REFLECT_101)
    outside = cv2.boxFilter((~inside).astype(np.uint8), cv2.CV_16U, size, normalize=False,
                            borderType=cv2.BORDER_REFLECT_101)
    return cost, outside == 0


def fit_segment_planes(left01: np.ndarray, right01: np.ndarray, disparity_px: np.ndarray,
                       *, census: tuple[np.ndarray, np.ndarray] | None = None
                       ) -> SegmentPlanes:
    """Make a left disparity map planar over colour segments where the images are indifferent.

    Parameters
    ----------
    left01, right01 : numpy.ndarray, (H, W, 3) or (H, W), uint8 or float in [0, 1]
        The rectified pair (RGB or grey). The segments are cut in the left image.
    disparity_px : numpy.ndarray, (H, W), float, pixels
        The left view's disparity, positive (``x_right = x_left - d``); NaN, inf or
        negative: no value.
    census : (numpy.ndarray, numpy.ndarray), optional
        The pair's census, as :func:`~.propagation.census_pair` returns it, if already
        computed (census propagation reads the same).

    Returns
    -------
    SegmentPlanes

    Raises
    ------
    ImageError
        An image of the wrong type, range or shape, images of different sizes, or a
        census that is not the pair's.
    DisparityError
        A disparity map that is not ``(H, W)`` of the images' size.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> right = rng.random((64, 96)).astype(np.float32) * 0.02 + 0.5  # a faint wall
    >>> left = np.roll(right, 8, axis=1)  # at 8 px
    >>> wandering = 8.0 + rng.uniform(-0.8, 0.8, (64, 96)).astype(np.float32)
    >>> flat = fit_segment_planes(left, right, wandering).disparity_px
    >>> measured = np.s_[:, 12:]  # right of the columns whose match leaves the image
    >>> [round(float(np.abs(d[measured] - 8.0).mean()), 1) for d in (wandering, flat)]
    [0.4, 0.1]
    """
    given = np.asarray(disparity_px)
    left01, right01, disparity_px = _checked(left01, right01, disparity_px, census)
    valued = np.isfinite(disparity_px)
    out = given.astype(np.float32).reshape(disparity_px.shape).copy()
    if not valued.any():
        return SegmentPlanes(out, 0.0, 0.0)
    labels = _segments(left01)
    plane, planar = _planes(labels, disparity_px)
    y, x = (axis.astype(np.float32) for axis in _coordinates(*disparity_px.shape))
    a, b, c = (plane[:, i].astype(np.float32).take(labels) for i in range(3))
    on_plane = a + b * x + c * y
    candidate = (valued & planar[labels] & (np.abs(on_plane - disparity_px) < REPLACE_PX)
                 & (on_plane >= 0))
    census_left, census_right = census if census is not None else census_pair(left01, right01)
    proposed = np.where(candidate, on_plane, disparity_px)
    own_cost, own_measured = _window_costs(census_left, census_right, disparity_px)
    plane_cost, plane_measured = _window_costs(census_left, census_right, proposed)
    tolerance = COST_TOLERANCE_BITS * WINDOW_PX * WINDOW_PX
    take = (candidate & own_measured & plane_measured
            & (plane_cost.astype(np.float32) <= own_cost + np.float32(tolerance)))
    out[take] = on_plane[take]
    return SegmentPlanes(out, float(take.mean()), float(planar.mean()))
