"""Census propagation: a backbone's disparity checked against the images, pixel by pixel.

A network that builds its cost volume at a quarter of the resolution and upsamples its
estimate smoothly spreads a foreground disparity over the background beside it and
through small gaps (between spokes, through a chair's back): its map is right region by
region but wrong along many edges, and where it is wrong over a whole region (background
seen through a gap wider than the offsets reach) no neighbour holds the right value. The
images can tell, in two steps, both judged by census matching costs
(:data:`CENSUS_RADIUS_PX`, summed over a :data:`WINDOW_PX` window) at the disparity
levels the map spans:

1. **Seeds.** Each pixel's best level over a wider :data:`SEED_WINDOW_PX` window (the
   window costs summed over it; the sub-pixel value from a parabola through the pixel's
   own window costs at the neighbouring levels) replaces the network's value where the
   right view's best level at the matching pixel agrees within one level, the wider cost
   is lower than the network's by :data:`SEED_MARGIN_BITS` bits per window pixel and it
   is a good match itself (:data:`SEED_MATCH_BITS`). The wider window makes a local match
   reliable where one window's texture is weak; the right view's agreement refuses the
   foreground a window drags over the occlusion beside it; the bounds leave the
   network's value wherever the images do not clearly contradict it.
2. **Propagation.** Each pixel is offered the disparities its neighbours hold
   :data:`OFFSETS_PX` away along its row and its column, and keeps the one whose window
   cost is lowest, if it beats the pixel's own by :data:`MARGIN_BITS` bits per window
   pixel and is a good match itself (:data:`MATCH_BITS`). Repeated :data:`ITERATIONS`
   times, a right value travels across a wrongly filled band up to
   ``ITERATIONS * max(OFFSETS_PX)`` px wide.

A pixel whose own match falls outside the right image (or too near its border for the
window) has no measured cost and keeps its value; so does a pixel without a value (NaN,
inf or negative, returned as given), which is never offered as a candidate either. Only
levels within the range of the map's own values are searched: the stage corrects where
the network put its estimates, not the range it saw.

The rules and constants were chosen on held-out rendered and procedural pairs outside
every benchmark (see the stand-in's record, ``inference``), as the left-right check was.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from srde_fusion._checks import check_disparity, check_image
from srde_fusion.errors import ImageError

__all__ = [
    "CENSUS_RADIUS_PX",
    "ITERATIONS",
    "MARGIN_BITS",
    "MATCH_BITS",
    "OFFSETS_PX",
    "SEED_MARGIN_BITS",
    "SEED_MATCH_BITS",
    "SEED_WINDOW_PX",
    "WINDOW_PX",
    "Propagated",
    "census_pair",
    "census_transform",
    "propagate_disparity",
]

#: Census of a (2 r + 1)^2 neighbourhood: 24 bits for r = 2.
CENSUS_RADIUS_PX = 2

#: Side of the square window the census costs are summed over, px.
WINDOW_PX = 5

#: Distances along the row and the column at which neighbours offer their disparity, px.
OFFSETS_PX = (3, 6, 12, 24)

#: Rounds of offers; values travel at most ``ITERATIONS * max(OFFSETS_PX)`` px.
ITERATIONS = 2

#: A neighbour's disparity replaces a pixel's own when its cost is lower by this many
#: differing census bits per window pixel.
MARGIN_BITS = 2.0

#: ... and only when it is a good match itself: at most this many differing bits per
#: window pixel (of 24). Where no value matches (an occlusion beside a foreground edge,
#: noise on a flat surface) every cost is high and the lowest of many offers would win
#: by chance.
MATCH_BITS = 6.0

#: Side of the square over which window costs are averaged for the seeds, px.
SEED_WINDOW_PX = 9

#: A seed replaces a pixel's value when its averaged cost is lower by this many differing
#: bits per window pixel ...
SEED_MARGIN_BITS = 1.0

#: ... and at most this many itself (of 24).
SEED_MATCH_BITS = 8.0

#: Largest cost volume held at once (bytes); larger images are run in row strips.
MAX_VOLUME_BYTES = 256 * 2**20

_UNMEASURED = np.iinfo(np.uint16).max

#: How far a pixel's window cost reads from it, px: the census radius plus half the window.
_COST_REACH_PX = CENSUS_RADIUS_PX + WINDOW_PX // 2


@dataclass(frozen=True)
class Propagated:
    """A disparity map after census propagation.

    Attributes
    ----------
    disparity_px : numpy.ndarray, (H, W), float32, pixels
        The corrected map; a pixel without a value (NaN, inf or negative) as given.
    changed_fraction : float
        Share of pixels whose value was replaced.
    """

    disparity_px: np.ndarray
    changed_fraction: float


def census_transform(grey: np.ndarray, radius: int = CENSUS_RADIUS_PX) -> np.ndarray:
    """Census of every pixel: one bit per neighbour, set where the neighbour is darker.

    Parameters
    ----------
    grey : numpy.ndarray, (H, W), float32
        Grey image (borders reflected).
    radius : int
        Neighbourhood radius; ``(2 radius + 1)^2 - 1 <= 32`` bits.

    Returns
    -------
    numpy.ndarray, (H, W), uint32

    Examples
    --------
    >>> grey = np.array([[0, 1, 2]] * 3, np.float32)
    >>> int(census_transform(grey, 1)[1, 1]).bit_count()  # the three darker neighbours
    3
    """
    height, width = grey.shape
    padded = cv2.copyMakeBorder(grey, radius, radius, radius, radius, cv2.BORDER_REFLECT_101)
    bits = np.zeros((height, width), np.uint32)
    bit = 0
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            if dy == 0 and dx == 0:
                continue
            neighbour = padded[radius + dy:radius + dy + height, radius + dx:radius + dx + width]
            darker = neighbour < grey
            bits |= darker.astype(np.uint32) << np.uint32(bit)
            bit += 1
    return bits


def _grey(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` float32 grey of a checked image (uint8 or float in [0, 1])."""
    image = image.astype(np.float32) / 255.0 if image.dtype == np.uint8 else image
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image


def _bit_counts(values: np.ndarray) -> np.ndarray:
    """Set bits of each uint32, uint8."""
    if hasattr(np, "bitwise_count"):  # numpy >= 2.0
        return np.bitwise_count(values)
    table = np.array([bin(i).count("1") for i in range(256)], np.uint8)
    return table[values.view(np.uint8).reshape(*values.shape, 4)].sum(axis=-1, dtype=np.uint8)


def _cost_volume(census_left: np.ndarray, census_right: np.ndarray, first: int, count: int
                 ) -> np.ndarray:
    """Window sums of census distances at integer disparities ``first .. first + count - 1``.

    ``(count + 1, H, W)`` uint16; a pixel whose right window at that disparity is not
    wholly inside the image holds ``_UNMEASURED``, and so does the last level throughout.
    """
    height, width = census_left.shape
    volume = np.full((count + 1, height, width), _UNMEASURED, np.uint16)
    for i in range(count):
        d = first + i
        start = d + _COST_REACH_PX  # first column whose right window lies inside
        if start >= width:
            continue
        distance = np.zeros((height, width), np.uint8)
        distance[:, d:] = _bit_counts(census_left[:, d:] ^ census_right[:, :width - d])
        summed = cv2.boxFilter(distance, cv2.CV_16U, (WINDOW_PX, WINDOW_PX), normalize=False,
                               borderType=cv2.BORDER_REFLECT_101)
        volume[i, :, start:] = summed[:, start:]
    return volume


def _shifted(values: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    """``out[y, x] = values[y - dy, x - dx]``; ``fill`` where that lies outside the map."""
    out = np.full_like(values, fill)
    height, width = values.shape
    if abs(dy) >= height or abs(dx) >= width:  # a shift past the map's edge: all fill
        return out
    out[max(dy, 0):height + min(dy, 0), max(dx, 0):width + min(dx, 0)] = \
        values[max(-dy, 0):height - max(dy, 0), max(-dx, 0):width - max(dx, 0)]
    return out


def _seeds(volume: np.ndarray, first: int, count: int, own_start: np.ndarray, plane: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pixel's best level over the wider seed window, and whether it replaces the own.

    Parameters
    ----------
    volume : numpy.ndarray, (count + 1, H, W), uint16
        Window costs from :func:`_cost_volume`.
    first : int
        Disparity of the first level, px.
    count : int
        Levels measured.
    own_start : numpy.ndarray, (H * W,), intp
        Each pixel's own level times ``plane`` (``count * plane``: none).
    plane : int
        ``H * W``.

    Returns
    -------
    take : numpy.ndarray, (H * W,), bool
        Pixels the seed replaces.
    level : numpy.ndarray, (H * W,), intp
        The seed's level.
    offset : numpy.ndarray, (H * W,), float32
        Its sub-pixel offset from that level, in [-0.5, 0.5].
    """
    shape = volume.shape[1:]
    width = shape[1]
    window = WINDOW_PX * WINDOW_PX * SEED_WINDOW_PX * SEED_WINDOW_PX  # cost terms in a sum
    # A sum above the largest measured one holds an unmeasured entry (65535): that level
    # is not measured over the wider window. Sums are clipped there, so that each fits
    # in 16 bits beside its level in 15: the smallest key is the lowest sum, its lowest
    # level on a tie, and one minimum per level keeps both.
    largest = ((2 * CENSUS_RADIUS_PX + 1) ** 2 - 1) * window
    level_bits = 15
    if count >= 2**level_bits or largest >= _UNMEASURED:
        return np.zeros(plane, bool), np.zeros(plane, np.intp), np.zeros(plane, np.float32)
    size = (SEED_WINDOW_PX, SEED_WINDOW_PX)
    best_key = np.full(shape, np.iinfo(np.int32).max, np.int32)
    # The right view's best for each of its pixels, from the same sums (a left pixel x at
    # level i is the right pixel x - first - i).
    right_key = best_key.copy()
    # The sum at each pixel's own level: its pixels listed per level once.
    own = np.full(plane, _UNMEASURED, np.int32)
    own_level = own_start // plane
    by_level = np.argsort(own_level.astype(np.int16), kind="stable")
    bounds = np.searchsorted(own_level[by_level], np.arange(count + 1))
    # One level at a time: the wider sums are never all held at once.
    for i in range(count):
        key = cv2.boxFilter(volume[i], cv2.CV_32S, size, normalize=False,
                            borderType=cv2.BORDER_REFLECT_101)
        # Unmeasured entries are the level's first columns (see _cost_volume): only the
        # sums that reach them can exceed 16 bits.
        edge = min(first + i + _COST_REACH_PX + SEED_WINDOW_PX // 2 + 1, width)
        np.minimum(key[:, :edge], _UNMEASURED, out=key[:, :edge])
        mine = by_level[bounds[i]:bounds[i + 1]]
        own[mine] = key.ravel().take(mine)
        np.left_shift(key, level_bits, out=key)
        np.bitwise_or(key, i, out=key)
        np.minimum(best_key, key, out=best_key)
        shift = first + i
        if shift < width:
            held = right_key[:, :width - shift]
            np.minimum(held, key[:, shift:], out=held)
    mask = 2**level_bits - 1
    level = best_key & mask
    # A seed the right view does not confirm (its best level there differs by more than
    # one) is the foreground a window drags over an occlusion: not taken.
    right_x = np.arange(width) - first - level
    right_says = np.take_along_axis(right_key, np.maximum(right_x, 0), axis=1) & mask
    confirmed = (right_x >= 0) & (np.abs(right_says - level) <= 1)
    level, best = level.ravel().astype(np.intp), (best_key >> level_bits).ravel()
    take = (confirmed.ravel() & (own <= largest) & (level != own_level)
            & (best + SEED_MARGIN_BITS * window < own)
            & (best <= SEED_MATCH_BITS * window))
    # The sub-pixel offset: the parabola through the seed's own window costs at its level
    # and the two beside it (none at the range's ends or where one is not measured).
    offset = np.zeros(plane, np.float32)
    inner = np.flatnonzero(take & (level > 0) & (level < count - 1))
    below, centre, above = (volume.ravel().take((level[inner] + step) * plane + inner)
                            .astype(np.float32) for step in (-1, 0, 1))
    curvature = below - 2 * centre + above
    fitted = (below < _UNMEASURED) & (above < _UNMEASURED) & (curvature > 0)
    offset[inner[fitted]] = 0.5 * (below - above)[fitted] / curvature[fitted]
    return take, level, offset


def census_pair(left01: np.ndarray, right01: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the census of both views of a checked pair, ``(H, W)`` uint32 each.

    Census propagation and segment planes both read it: an adapter running both computes
    it once and passes it to each (their ``census`` argument).
    """
    return census_transform(_grey(left01)), census_transform(_grey(right01))


def _checked(left01: np.ndarray, right01: np.ndarray, disparity_px: np.ndarray,
             census: tuple[np.ndarray, np.ndarray] | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check the image stages' inputs (one code for both stages).

    Returns the checked images and the disparity with NaN where there is no value; a
    given ``census`` must be the pair's.
    """
    left01, right01 = (check_image(image, name) for image, name in ((left01, "left"),
                                                                     (right01, "right")))
    if left01.shape[:2] != right01.shape[:2]:
        raise ImageError(f"right: expected the left image's size {left01.shape[:2]}, got "
                         f"{right01.shape[:2]}")
    disparity_px = check_disparity(disparity_px, left01.shape[:2], "disparity_px")
    if census is not None and not (
            isinstance(census, tuple) and len(census) == 2
            and all(isinstance(c, np.ndarray) and c.dtype == np.uint32
                    and c.shape == left01.shape[:2] for c in census)):
        raise ImageError(f"census: expected census_pair's two (H, W) uint32 arrays for "
                         f"images of size {left01.shape[:2]}, got {census!r:.80}")
    return left01, right01, disparity_px


def _propagate(census_left: np.ndarray, census_right: np.ndarray, disparity_px: np.ndarray,
               first: int, count: int) -> np.ndarray:
    """:func:`propagate_disparity` on one block, at integer disparities ``first`` + 0..count-1.

    The levels are the whole map's, so that every block's costs are the same arrays.
    """
    volume = _cost_volume(census_left, census_right, first, count)  # (count + 1, H, W)
    # Costs are read at ``rows + start``: ``rows`` the pixel, ``start`` the level's plane
    # (the last plane, never measured, for NaN and levels out of range).
    table = volume.ravel()
    plane = disparity_px.size
    rows = np.arange(plane, dtype=np.intp)
    margin = MARGIN_BITS * WINDOW_PX * WINDOW_PX

    def plane_start(values: np.ndarray) -> np.ndarray:
        level = values.ravel() - np.float32(first)
        inside = (level > -0.5) & (level < count - 0.5)  # False for NaN
        return np.where(inside, np.rint(level), count).astype(np.intp) * plane

    shape = disparity_px.shape
    current = disparity_px.ravel().copy()
    current_start = plane_start(current)
    # Which pixels have a measured cost of their own never changes: a seed or an offer is
    # only taken at a measured cost, by a pixel that had one.
    measured = table.take(rows + current_start) < _UNMEASURED
    seeded, level, sub_px = _seeds(volume, first, count, current_start, plane)
    seeded &= measured
    current[seeded] = (first + level[seeded] + sub_px[seeded]).astype(np.float32)
    current_start[seeded] = level[seeded] * plane
    # The cost of each pixel's value, kept up to date as values are taken.
    best_cost = table.take(rows + current_start).astype(np.float32)
    width = shape[1]
    for _ in range(ITERATIONS):
        best, best_start = current.copy(), current_start.copy()
        for offset in OFFSETS_PX:
            for dy, dx in ((0, offset), (0, -offset), (offset, 0), (-offset, 0)):
                offered_start = _shifted(current_start.reshape(shape), dy, dx,
                                         count * plane).ravel()
                # An offer at the level already held cannot be cheaper: not looked up.
                asked = np.flatnonzero(measured & (offered_start != best_start))
                offered_cost = table.take(asked + offered_start[asked])
                better = ((offered_cost + margin < best_cost[asked])
                          & (offered_cost <= MATCH_BITS * WINDOW_PX * WINDOW_PX))
                take = asked[better]
                # A pixel takes its neighbour's value: the one dy rows and dx columns back
                # (always inside the map, else its offer was unmeasured and not taken).
                best[take] = current[take - (dy * width + dx)]
                best_start[take] = offered_start[take]
                best_cost[take] = offered_cost[better]
        current, current_start = best, best_start
    return current.reshape(shape)


def propagate_disparity(left01: np.ndarray, right01: np.ndarray, disparity_px: np.ndarray,
                        *, census: tuple[np.ndarray, np.ndarray] | None = None) -> Propagated:
    """Correct a left disparity map where the images prefer a neighbour's value.

    Parameters
    ----------
    left01, right01 : numpy.ndarray, (H, W, 3) or (H, W), uint8 or float in [0, 1]
        The rectified pair (RGB or grey).
    disparity_px : numpy.ndarray, (H, W), float, pixels
        The left view's disparity, positive (``x_right = x_left - d``); NaN, inf or
        negative: no value.
    census : (numpy.ndarray, numpy.ndarray), optional
        The pair's census, as :func:`census_pair` returns it, if already computed.

    Returns
    -------
    Propagated

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
    >>> right = rng.random((40, 80)).astype(np.float32)
    >>> left = np.roll(right, 5, axis=1)  # every point 5 px further right in the left view
    >>> wrong = np.full((40, 80), 5.0, np.float32)
    >>> wrong[:, 40:46] = 12.0  # a band the network got wrong
    >>> fixed = propagate_disparity(left, right, wrong)
    >>> bool(np.all(fixed.disparity_px[:, 40:46] == 5.0))
    True
    """
    given = disparity_px
    left01, right01, disparity_px = _checked(left01, right01, disparity_px, census)
    height, width = disparity_px.shape
    finite = disparity_px[np.isfinite(disparity_px)]
    if finite.size == 0:
        return Propagated(np.asarray(given, np.float32).reshape(disparity_px.shape).copy(), 0.0)
    census_left, census_right = census if census is not None else census_pair(left01, right01)
    first = max(int(np.floor(finite.min())), 0)
    count = int(np.ceil(finite.max())) - first + 1
    rows = max(1, MAX_VOLUME_BYTES // (2 * count * width))
    if rows >= height:
        out = _propagate(census_left, census_right, disparity_px, first, count)
    else:
        # Row strips with a margin as wide as a value can travel (and the windows reach):
        # each strip's inner rows come out as they would from the whole image.
        reach = ITERATIONS * max(OFFSETS_PX) + _COST_REACH_PX + SEED_WINDOW_PX // 2
        rows = max(rows - 2 * reach, 1)
        out = np.empty_like(disparity_px)
        for top in range(0, height, rows):
            lo, hi = max(top - reach, 0), min(top + rows + reach, height)
            block = _propagate(census_left[lo:hi], census_right[lo:hi], disparity_px[lo:hi],
                               first, count)
            out[top:top + rows] = block[top - lo:top - lo + min(rows, height - top)]
    # A pixel without a value (NaN, inf or negative) is returned as it was given.
    empty = np.isnan(disparity_px)
    out[empty] = np.asarray(given, np.float32).reshape(out.shape)[empty]
    changed = ~(empty | (out == disparity_px))
    return Propagated(out, float(changed.mean()))


