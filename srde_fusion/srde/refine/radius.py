"""A light's radius fitted with the plane, when the rig does not know it.

A spherical lamp's highlight is its disc seen in the surface, blurred by the surface's
lobe. With the radius unknown, :func:`~.plane.refine_plane` renders a point light and
the lobe's fitted width absorbs the disc's extent. Where the highlight is seen in most
of the array's views this costs the plane next to nothing, but where few views see it
(a face of a faceted object lit in two to four views) the point light's lobe cannot
take the disc's shape in every view at once, and the plane tilts to make up for it. On
the end face of a three-face ridge seen in four views (lamp radius 6.9 mm, 0.64 m
from its plane), the fit from the true plane, with the true highlights and the face's true
mask, ended 0.23 px off as a point light and 0.03 px off with the lamp's radius; a
radius 25 % off ended 0.09-0.18 px off.

The fit's own cost says which radius it is: over the radius, on the same samples, it
has its minimum at the lamp's (there: 4.7e-6 for a point, 2.0e-6 at the true radius,
3.2e-6 at 1.25 times it). :func:`refine_plane_and_radius` therefore refits the plane for
a grid of radii, each the light's distance from the plane times an angle of
:data:`RADIUS_ANGLES_RAD`, in ascending order until the cost rises (or until the point
light's fit and the grid's first radii have all been refused, :data:`MAX_REFUSED_FITS`:
no disc then describes the highlight), takes the cheapest fit, and fits again at the
vertex of the parabola through the cheapest radius and its neighbours, a few times over.

A radius is taken only where it pays: if the cheapest radius lowers the point light's
cost by less than :data:`MIN_COST_GAIN`, the radius is not identifiable from these
samples and the point fit stands. On a valley's face seen in three views the cost was
0.7 % lower at 22.8 mm than as a point (the lamp's radius was 7.4 mm) and that radius
moved the plane from 0.21 to 0.23 px off; on the end face above it was 58 % lower.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import SRDEError
from ...geometry import Plane
from ...geometry.rig import MAX_LIGHT_RADIUS_M
from .plane import PlaneRefinement, refine_plane

__all__ = [
    "MAX_RADIUS_ANGLE_RAD",
    "MAX_REFUSED_FITS",
    "MIN_COST_GAIN",
    "RADIUS_ANGLES_RAD",
    "RADIUS_GROWTH",
    "RADIUS_NOTE",
    "VERTEX_STEPS",
    "VERTEX_TOLERANCE",
    "RadiusFit",
    "refine_plane_and_radius",
]

#: The grid of radii, as angles the lamp's radius subtends from the plane (its radius
#: over its distance from the plane), radians; 0 is a point light. The benchmarks' lamps
#: subtend 0.004-0.03 rad. Beyond the last the grid goes on by :data:`RADIUS_GROWTH` up to
#: :data:`MAX_RADIUS_ANGLE_RAD` (a 5 cm diffuser 0.5 m away subtends 0.1 rad). Radii are
#: tried in ascending order until the cost rises.
RADIUS_ANGLES_RAD = (0.0, 0.008, 0.016, 0.026, 0.04)

#: Factor between further angles of the grid beyond its last.
RADIUS_GROWTH = 1.5

#: The largest angle tried, radians.
MAX_RADIUS_ANGLE_RAD = 0.2

#: Fits at the vertex of the parabola through the cheapest radius and its neighbours,
#: each with the radii tried so far: the cost rises steeply above the lamp's radius, so
#: one parabola over the coarse grid lands wide of it.
VERTEX_STEPS = 3

#: The fraction of the point light's cost a radius must save to be taken: below it the
#: cost is flat over the radius, which the samples then do not fix, and the point fit
#: stands.
MIN_COST_GAIN = 0.05

#: How a result's note on a radius search begins (the estimator's, naming the radius
#: taken or why none was).
RADIUS_NOTE = "refinement: the light's radius is not known"

#: A vertex this close to a radius already tried (relative) ends the search.
VERTEX_TOLERANCE = 0.03

#: Fits refused in a row from the point light up (the point's and the grid's first radii)
#: that end the search: no disc tried gives a lobe that describes the highlight, and the
#: larger discs are the slow ones to fit. (On a three-face ridge's face read on a part
#: the refined planes redrew, every one of the grid's eight fits was refused, shape
#: parameters at their bounds, the five largest taking 1.4-3 s each: 10 s per reading.)
MAX_REFUSED_FITS = 3


@dataclass(frozen=True)
class RadiusFit:
    """Outcome of :func:`refine_plane_and_radius`.

    Parameters
    ----------
    refinement : PlaneRefinement
        The fit taken: the cheapest refined one, unless it saves less than
        :data:`MIN_COST_GAIN` of the point light's cost; then (or if no radius gave a
        refined fit) the point light's, whatever its status.
    light_radius_m : float
        The radius of that fit, metres (0: a point light).
    radii_m : tuple of float
        Every radius tried, metres, in the order tried.
    costs : tuple of float
        Each one's final photometric cost (mean squared residual, linear luminance
        squared); ``inf`` where its fit was not refined.
    min_gain : float
        The fraction of the point light's cost a radius had to save to be taken.
    """

    refinement: PlaneRefinement
    light_radius_m: float
    radii_m: tuple[float, ...]
    costs: tuple[float, ...]
    min_gain: float = MIN_COST_GAIN

    @property
    def point_cost(self) -> float:
        """The point light's cost (the first radius tried)."""
        return self.costs[0]

    @property
    def cheapest_radius_m(self) -> float:
        """The radius of the cheapest fit, metres, whether or not it was taken."""
        return self.radii_m[int(np.argmin(self.costs))]

    @property
    def saving(self) -> float:
        """The fraction of the point light's cost the cheapest fit saves (see ``min_gain``)."""
        return _saving(self.costs)


def refine_plane_and_radius(views, rig, light_m, mask: np.ndarray, initial_plane: Plane, *,
                            angles_rad: tuple[float, ...] = RADIUS_ANGLES_RAD,
                            min_gain: float = MIN_COST_GAIN, point_fit_needed: bool = False,
                            **options) -> RadiusFit:
    """:func:`~.plane.refine_plane` with the light's radius fitted too.

    Parameters
    ----------
    views, rig, light_m, mask, initial_plane
        As :func:`~.plane.refine_plane`.
    angles_rad : tuple of float
        The grid, as angles subtended from the initial plane (see
        :data:`RADIUS_ANGLES_RAD`), ascending, the first 0.
    min_gain : float
        The fraction of the point light's cost the cheapest radius must save to be
        taken (:data:`MIN_COST_GAIN`); 0 takes the cheapest fit.
    point_fit_needed : bool
        Take a radius only where the point light's fit was refined too (its saving then
        measured; a refused point fit ends the search); by default a radius that refines
        where the point light's fit was refused saves all of it.
    **options
        :func:`~.plane.refine_plane`'s other options, but ``light_radius_m``.

    Returns
    -------
    RadiusFit
        Every fit starts from ``initial_plane`` with the same windows, so their costs
        compare.
    """
    if isinstance(min_gain, bool) or not (isinstance(min_gain, (int, float))
                                          and 0.0 <= min_gain < 1.0):
        raise SRDEError(f"min_gain: expected a fraction in [0, 1), got {min_gain!r}")
    if not isinstance(point_fit_needed, bool):
        raise SRDEError(f"point_fit_needed: expected True or False, got {point_fit_needed!r}")
    light = np.asarray(light_m, dtype=np.float64)
    height_m = float(initial_plane.signed_distance(light))
    if not height_m > 0.0:  # refine_plane says why such a start is refused
        fit = refine_plane(views, rig, light, mask, initial_plane, **options)
        return RadiusFit(fit, 0.0, (0.0,), (_cost(fit),), min_gain)
    radii: list[float] = []
    fits: list[PlaneRefinement] = []
    costs: list[float] = []

    def fit_at(radius_m: float) -> None:
        radii.append(radius_m)
        fits.append(refine_plane(views, rig, light, mask, initial_plane,
                                 light_radius_m=radius_m if radius_m > 0.0 else None, **options))
        costs.append(_cost(fits[-1]))

    angles = list(angles_rad)
    while angles[-1] * RADIUS_GROWTH <= MAX_RADIUS_ANGLE_RAD:
        angles.append(angles[-1] * RADIUS_GROWTH)
    for angle in angles:
        if height_m * angle > MAX_LIGHT_RADIUS_M:
            break
        fit_at(height_m * angle)
        if point_fit_needed and not math.isfinite(costs[0]):
            break  # no radius can be taken: its saving has nothing to be measured against
        if len(costs) >= MAX_REFUSED_FITS and not any(map(math.isfinite, costs)):
            break
        if len(costs) > 1 and costs[-1] > min(costs[:-1]):
            # Past the cheapest radius: the cost rises steeply above the lamp's, and a
            # disc many lobe widths across is slow to fit (seconds where the others take
            # tens of milliseconds).
            break
    for _ in range(VERTEX_STEPS):
        # The parabola through the cheapest radius and its neighbours on either side.
        order = np.argsort(radii)
        at = int(np.argmin(np.asarray(costs)[order]))
        if not (0 < at < len(order) - 1 and all(math.isfinite(costs[i])
                                                for i in order[at - 1:at + 2])):
            break
        trio = order[at - 1:at + 2]
        r = _parabola_vertex([radii[i] for i in trio], [costs[i] for i in trio])
        if r is None or min(abs(r - x) for x in radii) <= VERTEX_TOLERANCE * r:
            break
        fit_at(r)
    best = int(np.argmin(costs))
    if not _saving(costs) >= min_gain:
        best = 0  # no radius refined, or one the cost hardly prefers to a point
    return RadiusFit(fits[best], radii[best], tuple(radii), tuple(costs), min_gain)


def _saving(costs) -> float:
    """Return the fraction ``1 - min(costs) / costs[0]`` of the point light's cost saved.

    1 if only the point light's fit was refused, NaN if every fit was.
    """
    cheapest = min(costs)
    if cheapest == costs[0]:
        return 0.0 if math.isfinite(cheapest) else math.nan
    return 1.0 - cheapest / costs[0]


def _cost(fit: PlaneRefinement) -> float:
    """Return a refined fit's final cost; ``inf`` for one that was not refined."""
    return fit.cost_final if fit.ok and math.isfinite(fit.cost_final) else math.inf


def _parabola_vertex(x, y) -> float | None:
    """Return the minimum of the parabola through three points, if one lies between them."""
    (x0, x1, x2), (y0, y1, y2) = x, y
    denominator = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / denominator
    b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / denominator
    if not a > 0.0:
        return None
    vertex = -b / (2.0 * a)
    return vertex if x0 < vertex < x2 else None
