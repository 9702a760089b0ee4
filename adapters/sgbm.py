"""OpenCV's semi-global block matching (StereoSGBM) as a backbone.

Classical stereo needs no model file, runs in tens of milliseconds on a CPU and is what
many pipelines use today. :class:`SGBMSpec` holds its parameters as data (validated, with
defaults scaled to the image width); :class:`SGBMStereo` runs it behind the one backbone
contract and undoes OpenCV's conventions: the int16 fixed-point output (disparity times
16) becomes float32 pixels, and the pixels it leaves empty (failed uniqueness, speckle or
left-right checks, the left border it cannot match) become NaN.

References
----------
H. Hirschmüller, "Stereo Processing by Semiglobal Matching and Mutual Information",
IEEE TPAMI 30(2), 2008 (the smoothness penalties P1 and P2). The width rule for the
disparity range and the penalties ``8 * cn * block**2`` and ``32 * cn * block**2`` are
those of OpenCV's ``stereo_match`` sample.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields, replace
from typing import Any, Literal

import cv2
import numpy as np

from srde_fusion.errors import BackboneError, ImageError

from ._pipeline import check_pair
from .consistency import seen_from_right

__all__ = ["SGBMSpec", "SGBMStereo", "SGBM_FIXED_POINT"]

logger = logging.getLogger(__name__)

#: StereoSGBM returns disparity times 16 as int16 (4 fractional bits).
SGBM_FIXED_POINT = 16.0
_DISPARITY_STEP = 16  # numDisparities must be a multiple of 16
_WIDTH_PER_DISPARITY = 8  # default range: a disparity of up to 1/8 of the image width
_P1_PER_CHANNEL_AREA = 8  # P1 = 8 * channels * block**2 (OpenCV's sample)
_P2_PER_CHANNEL_AREA = 32  # P2 = 32 * channels * block**2
_MODES = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
          "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}
_UINT8_MAX = 255.0

SGBMMode = Literal["sgbm", "hh", "3way", "hh4"]


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


@dataclass(frozen=True)
class SGBMSpec:
    """Parameters of OpenCV's StereoSGBM, with defaults scaled to the image.

    Fields left at ``None`` are derived from the image on each call: the disparity range
    from its width, the penalties from the block size and the number of channels matched.

    Parameters
    ----------
    name : str
        Label shown by ``describe()``.
    num_disparities : int, optional
        Size of the disparity search range, a positive multiple of 16. ``None``: the
        image width / 8 rounded up to a multiple of 16 (640 px -> 80, 741 px -> 96),
        at least 16.
    min_disparity : int
        Smallest disparity searched, px (0 for parallel rectified cameras).
    block_size : int
        Odd matching block side, px (1 to 11 is the useful range).
    p1, p2 : int, optional
        Penalties for a disparity change of 1 px and of more than 1 px between
        neighbours (``p2 > p1``). ``None``: ``8 * cn * block_size**2`` and
        ``32 * cn * block_size**2`` with ``cn`` the channels matched.
    disp12_max_diff : int
        OpenCV's own left-right check: largest allowed difference in px, ``-1`` to
        switch it off.
    pre_filter_cap : int
        Clip of the x-derivative prefilter (OpenCV's default 63).
    uniqueness_ratio : int
        Margin in percent by which the best cost must beat the second best (5 to 15).
    speckle_window_size : int
        Largest connected region of similar disparity removed as speckle, px (0: off).
    speckle_range : int
        Largest disparity variation inside one speckle region, px.
    mode : {"3way", "sgbm", "hh", "hh4"}
        ``"3way"`` (three path directions, fast and small), ``"sgbm"`` (five), ``"hh"``
        (full eight-path pass; memory grows with ``H * W * num_disparities``),
        ``"hh4"`` (four paths).
    colour : bool
        Match the three colour channels (``cn = 3``); ``False`` matches luminance.
    left_right_check : bool
        Also match right-to-left (on mirrored images) and empty every pixel that the
        right view contradicts: its right pixel has a disparity that differs by more than
        ``left_right_max_diff_px`` (pixels whose right pixel has none are kept). Costs a
        second match.
    left_right_max_diff_px : float
        Tolerance of ``left_right_check``, px.

    Examples
    --------
    >>> spec = SGBMSpec(block_size=7)
    >>> spec.num_disparities_for(640), spec.penalties(channels=3)
    (80, (1176, 4704))
    """

    name: str = "sgbm"
    num_disparities: int | None = None
    min_disparity: int = 0
    block_size: int = 5
    p1: int | None = None
    p2: int | None = None
    disp12_max_diff: int = 1
    pre_filter_cap: int = 63
    uniqueness_ratio: int = 10
    speckle_window_size: int = 100
    speckle_range: int = 2
    mode: SGBMMode = "3way"
    colour: bool = True
    left_right_check: bool = False
    left_right_max_diff_px: float = 1.0

    def __post_init__(self) -> None:
        if self.num_disparities is not None and not (
            _is_int(self.num_disparities) and self.num_disparities >= _DISPARITY_STEP
            and self.num_disparities % _DISPARITY_STEP == 0
        ):
            raise BackboneError(
                f"num_disparities: expected None or a positive multiple of 16, got "
                f"{self.num_disparities!r}"
            )
        if not _is_int(self.min_disparity):
            raise BackboneError(f"min_disparity: expected an integer (px), got "
                                f"{self.min_disparity!r}")
        if not (_is_int(self.block_size) and self.block_size >= 1 and self.block_size % 2 == 1):
            raise BackboneError(f"block_size: expected an odd integer >= 1, got "
                                f"{self.block_size!r}")
        for attr in ("p1", "p2"):
            value = getattr(self, attr)
            if value is not None and not (_is_int(value) and value > 0):
                raise BackboneError(f"{attr}: expected None or a positive integer, got {value!r}")
        if self.p1 is not None and self.p2 is not None and self.p2 <= self.p1:
            raise BackboneError(f"p2: expected a penalty larger than p1 ({self.p1}), got "
                                f"{self.p2}")
        if not (_is_int(self.disp12_max_diff) and self.disp12_max_diff >= -1):
            raise BackboneError(f"disp12_max_diff: expected an integer >= -1 (-1: off), got "
                                f"{self.disp12_max_diff!r}")
        for attr, low in (("pre_filter_cap", 1), ("uniqueness_ratio", 0),
                          ("speckle_window_size", 0), ("speckle_range", 0)):
            value = getattr(self, attr)
            if not (_is_int(value) and value >= low):
                raise BackboneError(f"{attr}: expected an integer >= {low}, got {value!r}")
        if self.mode not in _MODES:
            raise BackboneError(f"mode: expected one of {', '.join(_MODES)}, got {self.mode!r}")
        for attr in ("colour", "left_right_check"):
            if not isinstance(getattr(self, attr), bool):
                raise BackboneError(f"{attr}: expected True or False, got "
                                    f"{getattr(self, attr)!r}")
        diff = self.left_right_max_diff_px
        if isinstance(diff, bool) or not isinstance(diff, (int, float)) or not diff >= 0:
            raise BackboneError(f"left_right_max_diff_px: expected a number >= 0 (px), got "
                                f"{diff!r}")

    @property
    def channels(self) -> int:
        """Channels matched: 3 for colour, 1 for luminance."""
        return 3 if self.colour else 1

    def num_disparities_for(self, width: int) -> int:
        """Return the disparity range used for an image ``width`` px wide."""
        if self.num_disparities is not None:
            return self.num_disparities
        rough = math.ceil(width / _WIDTH_PER_DISPARITY)
        return max(_DISPARITY_STEP, math.ceil(rough / _DISPARITY_STEP) * _DISPARITY_STEP)

    def penalties(self, channels: int | None = None) -> tuple[int, int]:
        """``(p1, p2)``: the given ones, else scaled to the block area and channels."""
        cn = self.channels if channels is None else channels
        area = cn * self.block_size**2
        p1 = self.p1 if self.p1 is not None else _P1_PER_CHANNEL_AREA * area
        p2 = self.p2 if self.p2 is not None else _P2_PER_CHANNEL_AREA * area
        if p2 <= p1:
            raise BackboneError(f"p2: expected a penalty larger than p1 ({p1}), got {p2}")
        return p1, p2

    def replace(self, **changes: Any) -> SGBMSpec:
        """Return a copy with some fields changed (and validated again)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise BackboneError(
                f"SGBMSpec: expected field names ({', '.join(f.name for f in fields(self))}), "
                f"got unknown {', '.join(sorted(unknown))}"
            )
        return replace(self, **changes)

    def summary(self) -> str:
        """One line per non-default field, for ``describe()`` and logs."""
        default = SGBMSpec()
        lines = [f"SGBMSpec {self.name!r}:"]
        lines += [f"  {f.name} = {getattr(self, f.name)!r}" for f in fields(self)
                  if f.name != "name" and getattr(self, f.name) != getattr(default, f.name)]
        if len(lines) == 1:
            lines.append("  (all defaults)")
        return "\n".join(lines)


class SGBMStereo:
    """OpenCV StereoSGBM as a ``backbone(left, right) -> disparity`` callable.

    Parameters
    ----------
    spec : SGBMSpec, optional
        The matcher's parameters (the defaults of :class:`SGBMSpec` when None).
    **changes
        Fields of :class:`SGBMSpec` to change, e.g. ``block_size=7``.

    Raises
    ------
    BackboneError
        A parameter out of its range, or an unknown one.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> right = rng.integers(0, 256, (48, 96, 3), dtype=np.uint8)
    >>> left = np.roll(right, 6, axis=1)  # every point 6 px further right in the left view
    >>> disparity_px = SGBMStereo()(left, right)
    >>> float(np.nanmedian(disparity_px))
    6.0
    """

    def __init__(self, spec: SGBMSpec | None = None, **changes: Any) -> None:
        if spec is None:
            spec = SGBMSpec()
        if not isinstance(spec, SGBMSpec):
            raise BackboneError(f"spec: expected an SGBMSpec, got {type(spec).__name__}")
        self.spec = spec.replace(**changes) if changes else spec
        self.spec.penalties()  # p1/p2 given only one-sided: check the pair now, not per call

    def matcher(self, width: int) -> Any:
        """Return the ``cv2.StereoSGBM`` object for images ``width`` px wide.

        Raises
        ------
        ImageError
            Images too narrow for the disparity range: OpenCV then fails with an
            allocation error of a negative size, which may leave the process corrupt.
        """
        spec = self.spec
        num_disparities = spec.num_disparities_for(width)
        # Measured (OpenCV 5.0): "sgbm" and "hh" need width > min_disparity +
        # num_disparities + block_size // 2, "3way" width > num_disparities +
        # max(min_disparity, 0); the larger of the two holds for every mode.
        limit = num_disparities + max(spec.min_disparity, 0) + spec.block_size // 2
        if width <= limit:
            raise ImageError(
                f"images: expected a width above {limit} px for SGBM (num_disparities "
                f"{num_disparities}, min_disparity {spec.min_disparity}, "
                f"block_size {spec.block_size}), got {width} px; a narrower image needs a "
                f"smaller disparity range (num_disparities is at least 16)")
        p1, p2 = spec.penalties()
        return cv2.StereoSGBM_create(
            minDisparity=spec.min_disparity, numDisparities=num_disparities,
            blockSize=spec.block_size, P1=p1, P2=p2, disp12MaxDiff=spec.disp12_max_diff,
            preFilterCap=spec.pre_filter_cap, uniquenessRatio=spec.uniqueness_ratio,
            speckleWindowSize=spec.speckle_window_size, speckleRange=spec.speckle_range,
            mode=_MODES[spec.mode],
        )

    def __call__(self, left: Any, right: Any) -> np.ndarray:
        """Disparity of a rectified stereo pair.

        Parameters
        ----------
        left, right : numpy.ndarray, (H, W, 3) or (H, W), uint8 or float in [0, 1]
            Rectified RGB (or grey) images of the left and right camera.

        Returns
        -------
        numpy.ndarray, (H, W), float32, pixels
            Disparity of the left image, positive; NaN where the matcher found none.

        Raises
        ------
        ImageError
            Wrong image type, dtype, shape or mismatched sizes, or images too narrow for
            the disparity range (see :meth:`matcher`).
        """
        left01, right01 = check_pair(left, right)
        left8, right8 = self._matching_images(left01), self._matching_images(right01)
        matcher = self.matcher(left8.shape[1])
        disparity_px = _to_pixels(matcher.compute(left8, right8), self.spec.min_disparity)
        if self.spec.left_right_check:
            # The right view's disparity: match the mirrored pair (mirroring turns the
            # right image into a left one whose points lie further right), mirror back.
            mirrored = matcher.compute(np.ascontiguousarray(right8[:, ::-1]),
                                       np.ascontiguousarray(left8[:, ::-1]))
            right_px = _to_pixels(mirrored, self.spec.min_disparity)[:, ::-1]
            disparity_px = _left_right_consistent(disparity_px, right_px,
                                                  self.spec.left_right_max_diff_px)
        return disparity_px

    def _matching_images(self, image01: np.ndarray) -> np.ndarray:
        image8 = np.clip(np.rint(image01 * _UINT8_MAX), 0, _UINT8_MAX).astype(np.uint8)
        if self.spec.colour:
            return np.ascontiguousarray(image8)
        return cv2.cvtColor(image8, cv2.COLOR_RGB2GRAY)

    def describe(self) -> str:
        """Say which parameters are set and which are derived from each image."""
        spec = self.spec
        p1, p2 = spec.penalties()
        range_text = (f"{spec.num_disparities} disparities" if spec.num_disparities is not None
                      else "disparities: image width / 8, rounded up to a multiple of 16")
        return "\n".join([
            "SGBMStereo (OpenCV StereoSGBM)",
            spec.summary(),
            "derived:",
            f"  {range_text}, from {spec.min_disparity} px",
            f"  P1 = {p1}, P2 = {p2} ({'colour' if spec.colour else 'luminance'}, "
            f"block {spec.block_size})",
            "  output: int16 / 16 -> float32 px; empty pixels (OpenCV's invalid value) -> NaN",
            f"  left-right check: {'on' if spec.left_right_check else 'off'} "
            f"(OpenCV disp12MaxDiff = {spec.disp12_max_diff})",
        ])

    def __repr__(self) -> str:
        return f"SGBMStereo({self.spec!r})"


def _to_pixels(raw: np.ndarray, min_disparity: int) -> np.ndarray:
    """int16 fixed-point disparity -> float32 px, OpenCV's invalid value -> NaN."""
    disparity_px = raw.astype(np.float32) / np.float32(SGBM_FIXED_POINT)
    # OpenCV writes (min_disparity - 1) * 16 where it found no disparity.
    disparity_px[raw < min_disparity * SGBM_FIXED_POINT] = np.nan
    return disparity_px


def _left_right_consistent(left_px: np.ndarray, right_px: np.ndarray,
                           max_diff_px: float) -> np.ndarray:
    """Empty the left disparities that the right view's disparity contradicts.

    A left pixel ``(y, x)`` with disparity ``d`` sees the right pixel ``x - d``; where
    that pixel has a disparity, it must be ``d`` within ``max_diff_px``. Where it has
    none (the right image's own unmatched border), nothing contradicts the left value.
    """
    inside, seen = seen_from_right(left_px, right_px)
    with np.errstate(invalid="ignore"):
        contradicted = inside & (np.abs(seen - left_px) > max_diff_px)
    return np.where(contradicted, np.float32(np.nan), left_px).astype(np.float32)
