"""Hinge planes: a face's plane from its neighbour's plane and the edge they share.

A face whose highlights are cut by the outline on one side and by its edge with a
neighbour on the other has blob centres pixels off its light's: no plane proposed from
them lies near the face. Its neighbour's plane may be known well, and the edge the two
share is in the image: where the outline of the object turns at both ends of the edge
(a row of flat faces has its outline bent at every edge's ends). The edge on the
neighbour's plane is a 3-D line, and the face's plane is one of the planes through it,
one angle about the line to find. Each light's mirror image across those planes runs
round a circle about the line; the angle is the one whose mirror images land on the
most candidates, in every view at once, on the far side of the edge. Centres a few
pixels off still fix one angle well where they cannot fix a plane's three parameters.

:func:`outline_corners` finds where the outline turns; :func:`hinge_chords` the pairs of
corners an edge can join; :func:`hinge_plane` the plane through one of them.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..geometry import CameraRig, Plane, plane_depth, project_points

__all__ = [
    "HINGE_MIN_ANGLE_DEG",
    "hinge_chords",
    "hinge_plane",
    "outline_corners",
]

#: Tolerance (pixels) of the polygon the outline is simplified to: straight stretches of
#: the pixel outline stray from their line by about a pixel.
OUTLINE_POLYGON_PX = 1.5

#: Fraction of each side of a polygon's vertex left out when its corner is found again:
#: the stretch searched runs between the middles of its sides, so that only one turn of
#: the outline lies in it.
SIDE_TRIM = 0.5

#: Faces meeting at less than this angle (degrees) are one plane to the highlights.
HINGE_MIN_ANGLE_DEG = 5.0

# Angles about the edge tried first (degrees): both ways up to grazing, then the best
# refined on a finer grid around it.
_COARSE_STEP_DEG = 0.25
_FINE_HALF_WIDTH_DEG = 0.5
_FINE_STEPS = 201

# A chord is inside the mask when these fractions along it are (its ends lie on the
# outline, where rounding can put them a pixel out).
_CHORD_SAMPLES = np.linspace(0.1, 0.9, 17)


def outline_corners(mask: np.ndarray) -> np.ndarray:
    """Return where the object's outline turns, to a fraction of a pixel, ``(M, 2)`` float.

    The outer outline of the mask's largest part is simplified to a polygon
    (:data:`OUTLINE_POLYGON_PX`). A polygon's vertex is an outline pixel: on a shallow bend,
    a step of the pixel outline several pixels from the true corner. Each corner is found
    again between the middles of its two sides (:data:`SIDE_TRIM`) as the split of that
    stretch of outline into two straight lines that fit it best, and is where those lines
    cross (the split's pixel if they are nearly parallel).

    Parameters
    ----------
    mask : numpy.ndarray, (H, W) bool

    Returns
    -------
    numpy.ndarray, (M, 2)
        Corners ``(u, v)`` in pixels, in order round the outline; empty if the mask
        has no part with three corners.
    """
    contours, _ = cv2.findContours(mask.view(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2))
    contour = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float64)
    polygon = cv2.approxPolyDP(contour.astype(np.int32).reshape(-1, 1, 2), OUTLINE_POLYGON_PX,
                               True).reshape(-1, 2)
    m, n = len(polygon), len(contour)
    if m < 3:
        return np.zeros((0, 2))
    # Each vertex's place on the contour (approxPolyDP returns points of it).
    index = [int(np.flatnonzero((contour == p).all(axis=1))[0]) for p in polygon]
    corners = np.empty((m, 2))
    for i in range(m):
        before = (index[i] - index[i - 1]) % n
        after = (index[(i + 1) % m] - index[i]) % n
        first = index[i] - before + int(SIDE_TRIM * before)
        stretch = contour[np.arange(first, index[i] + after - int(SIDE_TRIM * after) + 1) % n]
        corners[i] = _two_line_corner(stretch)
    return corners


def _two_line_corner(points: np.ndarray) -> np.ndarray:
    """Return the corner of a stretch of outline ``(P, 2)`` that turns once, ``(2,)``.

    Every split into two runs (each of at least two points) is scored by the two
    total-least-squares lines' squared residuals, from running sums; the best split's
    lines are crossed.
    """
    count = len(points)
    if count < 4:
        return points[count // 2].copy()
    x, y = points[:, 0], points[:, 1]
    sums = [np.concatenate([[0.0], np.cumsum(v)]) for v in (np.ones(count), x, y, x * x,
                                                               y * y, x * y)]

    def residual(lo, hi):
        k, sx, sy, sxx, syy, sxy = (s[hi] - s[lo] for s in sums)
        cxx, cyy, cxy = sxx - sx * sx / k, syy - sy * sy / k, sxy - sx * sy / k
        # The smaller eigenvalue of the scatter matrix: the residual of the best line.
        return 0.5 * (cxx + cyy - np.sqrt((cxx - cyy) ** 2 + 4.0 * cxy * cxy))

    split = np.arange(2, count - 1)  # first run points[:split], second points[split - 1:]
    zero = np.zeros_like(split)
    full = np.full_like(split, count)
    cost = residual(zero, split) + residual(split - 1, full)
    b = int(split[np.argmin(cost)])
    crossing = _crossing(_line(points[:b]), _line(points[b - 1:]))
    if crossing is None or np.hypot(*(crossing - points[b - 1])) > 0.5 * count:
        return points[b - 1].copy()
    return crossing


def _line(points: np.ndarray):
    """Total-least-squares line ``(point, direction)`` through ``points`` ``(P, 2)``."""
    center = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - center, full_matrices=False)
    return center, vt[0]


def _crossing(a, b) -> np.ndarray | None:
    """Return where two lines ``(point, direction)`` cross; None if nearly parallel."""
    (p, d), (q, e) = a, b
    det = d[0] * (-e[1]) - d[1] * (-e[0])
    if abs(det) < 1e-6:
        return None
    s = ((q[0] - p[0]) * (-e[1]) - (q[1] - p[1]) * (-e[0])) / det
    return p + s * d


def hinge_chords(mask: np.ndarray, corners: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Return the pairs of outline corners an edge between two faces can join, ``(p0, p1)``.

    Corners not next to each other round the outline whose chord runs inside the mask.
    """
    m = len(corners)
    height, width = mask.shape
    chords = []
    for i in range(m):
        for j in range(i + 2, m):
            if i == 0 and j == m - 1:
                continue  # neighbours round the outline
            p0, p1 = corners[i], corners[j]
            along = p0 + _CHORD_SAMPLES[:, None] * (p1 - p0)
            u = np.clip(np.rint(along[:, 0]).astype(np.intp), 0, width - 1)
            v = np.clip(np.rint(along[:, 1]).astype(np.intp), 0, height - 1)
            if mask[v, u].all():
                chords.append((p0, p1))
    return chords


def hinge_plane(rig: CameraRig, lights_m: np.ndarray, mask: np.ndarray, source: Plane,
                chord: tuple[np.ndarray, np.ndarray], source_uv: np.ndarray,
                candidates_uv: list[np.ndarray], tolerances_px: tuple[float, ...]
                ) -> list[tuple[Plane, int]]:
    """Return the planes through a chord's line on ``source`` that explain most candidates.

    The chord's ends, seen in the reference view, lie on ``source`` at a 3-D line; the
    planes through it are ``source`` turned about it. For each angle (both ways from
    :data:`HINGE_MIN_ANGLE_DEG` to grazing), every light in front of the plane is
    mirrored across it and its image in every view matched to that view's nearest
    candidate, counted when within the tolerance and reflected on the object, on the far
    side of the chord from ``source``'s own highlights (their reference mirror points
    ``source_uv`` ``(M, 2)``). The angle with the most candidates (then the least squared
    distance) is found on a coarse grid with the widest tolerance, then, for each
    tolerance, on a fine grid around it. (Turning the plane by a tenth of a degree moves a
    virtual light a metre away by about 3 mm, several pixels: only a wide tolerance
    keeps a coarse grid from stepping over the answer.)

    Parameters
    ----------
    rig : CameraRig
    lights_m : numpy.ndarray, (K, 3), metres
    mask : numpy.ndarray, (H, W) bool
        The object in the reference view.
    source : Plane
        The neighbouring face's plane.
    chord : (numpy.ndarray, numpy.ndarray)
        The edge's ends ``(u, v)`` in the reference view, pixels.
    source_uv : numpy.ndarray, (M, 2)
        Where ``source``'s explained highlights reflect, seen from the reference camera.
    candidates_uv : list of N numpy.ndarray, each (m_j, 2)
        Every view's highlight candidates, pixels.
    tolerances_px : tuple of float
        Distances within which a candidate explains a predicted highlight.

    Returns
    -------
    list of (Plane, int)
        Per tolerance whose best angle explains a candidate: the plane and the
        candidates it explains. Empty when the chord's ends miss ``source`` or
        ``source``'s highlights lie on both sides of it.
    """
    p0, p1 = (np.asarray(p, dtype=np.float64) for p in chord)
    normal_px = np.array([p0[1] - p1[1], p1[0] - p0[0]])
    sides = np.sign((np.asarray(source_uv, dtype=np.float64) - p0) @ normal_px)
    if sides.size == 0 or not (np.all(sides > 0) or np.all(sides < 0)):
        return []
    ends_uv = np.stack([p0, p1])
    depth_m = plane_depth(source, rig, ends_uv)
    if not np.all(np.isfinite(depth_m)):
        return []
    ends = rig.backproject(ends_uv, depth_m)
    direction = ends[1] - ends[0]
    direction /= np.linalg.norm(direction)
    turn = np.cross(direction, source.n)
    turn /= np.linalg.norm(turn)
    scene = _HingeScene(rig, np.atleast_2d(lights_m), mask, ends[0], source.n, turn, p0,
                        normal_px, -sides[0], candidates_uv)
    coarse = np.radians(np.concatenate([
        np.arange(-90.0 + _COARSE_STEP_DEG, -HINGE_MIN_ANGLE_DEG + 1e-9, _COARSE_STEP_DEG),
        np.arange(HINGE_MIN_ANGLE_DEG, 90.0 - 1e-9, _COARSE_STEP_DEG)]))
    count, cost = scene.explained(coarse, max(tolerances_px))
    best = _best(count, cost)
    if count[best] == 0:
        return []
    half = math.radians(_FINE_HALF_WIDTH_DEG)
    fine = np.linspace(coarse[best] - half, coarse[best] + half, _FINE_STEPS)
    found = []
    for tolerance_px in tolerances_px:
        count, cost = scene.explained(fine, tolerance_px)
        best = _best(count, cost)
        if count[best] > 0:
            found.append((scene.plane(fine[best]), int(count[best])))
    return found


def _best(count: np.ndarray, cost: np.ndarray) -> int:
    """Index of the most candidates explained, then the least squared distance."""
    return int(np.lexsort((cost, -count))[0])


class _HingeScene:
    """The planes through one 3-D line and what each angle about it explains."""

    def __init__(self, rig: CameraRig, lights_m: np.ndarray, mask: np.ndarray,
                 point_m: np.ndarray, normal: np.ndarray, turn: np.ndarray, p0: np.ndarray,
                 normal_px: np.ndarray, far_side: float, candidates_uv) -> None:
        self.rig, self.lights, self.mask = rig, lights_m, mask
        self.point, self.normal, self.turn = point_m, normal, turn
        self.p0, self.normal_px, self.far_side = p0, normal_px, far_side
        cands = [np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in candidates_uv]
        # Every view's candidates in one (N, M, 2) array, padded far away, so that all
        # views are matched in one pass.
        self.cands = np.full((len(cands), max(1, max(len(c) for c in cands)), 2), 1e9)
        for j, c in enumerate(cands):
            self.cands[j, :len(c)] = c

    def normals(self, angles: np.ndarray) -> np.ndarray:
        """Return unit normals ``(A, 3)`` turned by ``angles`` ``(A,)`` rad, facing the cameras."""
        n = np.cos(angles)[:, None] * self.normal + np.sin(angles)[:, None] * self.turn
        facing = (self.rig.reference_center_m - self.point) @ n.T
        return np.where(facing[:, None] < 0.0, -n, n)

    def plane(self, angle: float) -> Plane:
        n = self.normals(np.array([angle]))[0]
        return Plane(tuple(float(x) + 0.0 for x in n), float(n @ self.point))

    def explained(self, angles: np.ndarray, tolerance_px: float
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Candidates explained ``(A,)`` int and their squared distances ``(A,)`` per angle."""
        rig = self.rig
        n = self.normals(angles)                                   # (A, 3)
        offset = n @ self.point                                    # (A,)
        height = n @ self.lights.T - offset[:, None]               # (A, K)
        virtual = self.lights[None] - 2.0 * height[..., None] * n[:, None, :]  # (A, K, 3)
        rel = virtual[:, :, None, :] - rig.centers_m               # (A, K, N, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            # Where the segment from each camera to the virtual light meets the plane,
            # seen from the reference camera.
            s = (offset[:, None] - n @ rig.centers_m.T)[:, None, :] \
                / np.einsum("aknx,ax->akn", rel, n)
            seen = rig.project(rig.centers_m + s[..., None] * rel)  # (A, K, N, 2), NaN behind
        height_px, width_px = self.mask.shape
        col, row = np.rint(seen[..., 0]), np.rint(seen[..., 1])
        ask = (height[..., None] > 0.0) & (rel[..., 2] > 0.0) & (s > 0.0) & (s < 1.0) \
            & (col >= 0) & (col < width_px) & (row >= 0) & (row < height_px)
        ask &= np.sign((seen - self.p0) @ self.normal_px) == self.far_side
        a, light, view = np.nonzero(ask)
        on_object = self.mask[row[a, light, view].astype(np.intp),
                              col[a, light, view].astype(np.intp)]
        a, light, view = a[on_object], light[on_object], view[on_object]
        # Only predictions reflected on the object beyond the chord meet the candidates.
        uv = project_points(rig, virtual[a, light], view)          # (P, 2)
        cands = self.cands[view]                                   # (P, M, 2)
        du = uv[:, None, 0] - cands[..., 0]
        dv = uv[:, None, 1] - cands[..., 1]
        gap2 = (du * du + dv * dv).min(axis=1)
        ok = gap2 <= tolerance_px * tolerance_px
        count = np.bincount(a[ok], minlength=len(angles))
        cost = np.bincount(a[ok], gap2[ok], minlength=len(angles))
        return count, cost
