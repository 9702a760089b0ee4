"""The camera rig: a rectified array of identical pinhole cameras and, optionally, a light.

Frame conventions (DESIGN §2): the *array frame* is the reference camera's OpenCV frame
(x right, y down, z forward, metres). All cameras share orientation and intrinsics and
differ only by their centre, which lies in the reference camera's ``z = const`` plane.
Disparity is for the stereo pair (reference = left, partner to its right):
``d = fx * B / z``.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .._checks import MAX_IMAGE_PIXELS, check_keys, check_number
from .._json import dump_json, load_json_source
from ..errors import LightError, RigError, SRDEError
from ..imaging import IMAGE_ENCODINGS

__all__ = [
    "Intrinsics",
    "Camera",
    "CameraRig",
    "RigLight",
    "RIG_FORMAT",
    "project_points",
    "MAX_FOCAL_PX",
    "MAX_PRINCIPAL_OFFSET",
    "MAX_POSITION_M",
    "MIN_BASELINE_M",
    "MAX_LIGHTS",
    "MAX_LIGHT_RADIUS_M",
    "MIN_LIGHT_SEPARATION_M",
]

RIG_FORMAT = "srde-rig/1"
# Centres must be coplanar to this tolerance for the array to count as rectified.
_COPLANAR_TOL_M = 1e-6

# Generous physical ranges of a rig's numbers. A value outside is a typo or a unit
# mix-up (millimetres for metres, a focal length in metres), never a camera: the search
# geometry and every per-pixel array scale with these numbers, so they are refused early.
#: Largest focal length, pixels (a 1 m telephoto lens on 1 um pixels).
MAX_FOCAL_PX = 1e6
#: The principal point may lie this many image widths (heights) outside the image.
MAX_PRINCIPAL_OFFSET = 10.0
#: Largest distance of a camera centre or the light from the array's origin, metres.
MAX_POSITION_M = 1e3
#: Shortest stereo baseline, metres.
MIN_BASELINE_M = 1e-6
#: Most lights a rig may list (a lamp rack, not a light field).
MAX_LIGHTS = 16
#: Largest light radius, metres: beyond it the "small light" of the method is a room.
MAX_LIGHT_RADIUS_M = 1.0
#: Lights closer than this are one light listed twice (their highlights coincide).
MIN_LIGHT_SEPARATION_M = 1e-3
#: Longest light name, characters.
_MAX_NAME_CHARS = 128


def _number(value: Any, field_name: str, *, positive: bool = False) -> float:
    return check_number(value, field_name, RigError, positive=positive)


def _vector3(value: Any, field_name: str, error: type[SRDEError] = RigError
             ) -> tuple[float, float, float]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise RigError(
            f"{field_name}: expected a list of 3 numbers [x, y, z] in metres, got {value!r}"
        )
    out = tuple(_number(v, f"{field_name}[{i}]") for i, v in enumerate(value))
    # Each coordinate first: squaring 1e300 would overflow.
    norm = math.inf if max(map(abs, out)) >= MAX_POSITION_M else math.hypot(*out)
    if norm >= MAX_POSITION_M:
        raise error(
            f"{field_name}: expected a position within {MAX_POSITION_M:g} m of the array's "
            f"origin (metres, not millimetres), got {list(out)}"
        )
    return out  # type: ignore[return-value]


def _check_keys(data: Any, allowed: set[str], required: set[str], where: str) -> None:
    check_keys(data, allowed, required, where, RigError)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics shared by every camera of a rectified rig.

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels (the paper's f/p).
    cx, cy : float
        Principal point in pixels; pixel centres are at integer coordinates.
    """

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        # Stored as Python floats so that the rig serialises to JSON whatever the input type.
        for name in ("fx", "fy"):
            value = _number(getattr(self, name), f"intrinsics.{name}", positive=True)
            if value >= MAX_FOCAL_PX:
                raise RigError(
                    f"intrinsics.{name}: expected a focal length in pixels below "
                    f"{MAX_FOCAL_PX:g}, got {value:g}"
                )
            object.__setattr__(self, name, value)
        for name in ("cx", "cy"):
            object.__setattr__(self, name, _number(getattr(self, name), f"intrinsics.{name}"))

    @classmethod
    def from_focal_length(
        cls, focal_length_mm: float, pixel_size_um: float, cx: float, cy: float
    ) -> Intrinsics:
        """Intrinsics from a lens focal length (mm) and a square pixel pitch (µm)."""
        f_mm = _number(focal_length_mm, "focal_length_mm", positive=True)
        p_um = _number(pixel_size_um, "pixel_size_um", positive=True)
        f_px = f_mm * 1000.0 / p_um
        return cls(f_px, f_px, cx, cy)

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Camera:
    """One camera of the rig: a name and its centre in the array frame (metres)."""

    name: str
    center_m: tuple[float, float, float]


def _light_fields(position: Any, radius_m: Any, name: Any, where: str,
                  error: type[SRDEError]) -> tuple[tuple[float, float, float], float | None,
                                                   str | None]:
    """Validate one light's fields; ``where`` names it in messages (``light[1]``)."""
    pos = _vector3(position, f"{where}.position", error)
    if radius_m is not None:
        radius_m = check_number(radius_m, f"{where}.radius_m", error)
        if not 0.0 <= radius_m <= MAX_LIGHT_RADIUS_M:
            raise error(
                f"{where}.radius_m: expected a radius in [0, {MAX_LIGHT_RADIUS_M:g}] m "
                f"(metres, not millimetres), got {radius_m:g}"
            )
    if name is not None and (
        not isinstance(name, str) or not name.strip() or len(name) > _MAX_NAME_CHARS
    ):
        raise error(
            f"{where}.name: expected a non-empty string of at most {_MAX_NAME_CHARS} "
            f"characters, got {name!r:.80}"
        )
    return pos, radius_m, name


@dataclass(frozen=True)
class RigLight:
    """One known light of the rig.

    Parameters
    ----------
    position_m : (float, float, float)
        Centre of the light in the array frame, metres.
    radius_m : float or None
        Radius of a spherical light, metres (0 = a point); None when not known.
    name : str or None
        A label for messages and reports ("left lamp"); None when unnamed.

    Examples
    --------
    >>> RigLight((0.1, -0.4, 0.2), radius_m=0.005).to_dict()
    {'position': [0.1, -0.4, 0.2], 'radius_m': 0.005}
    """

    position_m: tuple[float, float, float]
    radius_m: float | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        pos, radius, name = _light_fields(self.position_m, self.radius_m, self.name, "light",
                                          LightError)
        object.__setattr__(self, "position_m", pos)
        object.__setattr__(self, "radius_m", radius)
        object.__setattr__(self, "name", name)

    @property
    def position(self) -> np.ndarray:
        """The position as ``(3,)`` float64, metres."""
        return np.array(self.position_m)

    def to_dict(self) -> dict[str, Any]:
        """Return the light's entry in ``rig.json``: its position, then the optional fields."""
        out: dict[str, Any] = {"position": list(self.position_m)}
        if self.radius_m is not None:
            out["radius_m"] = self.radius_m
        if self.name is not None:
            out["name"] = self.name
        return out


def _check_lights(lights: Any, error: type[SRDEError]) -> tuple[RigLight, ...]:
    """Validate a rig's lights as a whole: a tuple of RigLight, distinct, uniquely named."""
    if lights is None:
        return ()
    if isinstance(lights, RigLight):
        lights = (lights,)
    if not isinstance(lights, (tuple, list)):
        raise error(f"lights: expected a sequence of RigLight, got {type(lights).__name__}")
    if len(lights) > MAX_LIGHTS:
        raise error(f"lights: expected at most {MAX_LIGHTS} lights, got {len(lights)}")
    for i, light in enumerate(lights):
        if not isinstance(light, RigLight):
            raise error(f"lights[{i}]: expected a RigLight, got {type(light).__name__}")
    positions = np.array([light.position_m for light in lights]).reshape(-1, 3)
    for i in range(len(lights)):
        for j in range(i):
            gap = float(np.linalg.norm(positions[i] - positions[j]))
            if gap < MIN_LIGHT_SEPARATION_M:
                raise error(
                    f"light[{i}].position: expected a light at least "
                    f"{MIN_LIGHT_SEPARATION_M * 1000:g} mm from every other, got "
                    f"{gap * 1000:.3g} mm from light[{j}] (one light listed twice?)"
                )
    names = [light.name for light in lights if light.name is not None]
    if len(set(names)) != len(names):
        raise error(f"light names: expected unique names, got {names}")
    return tuple(lights)


@dataclass(frozen=True)
class CameraRig:
    """A rectified multi-camera rig with an optional known light position.

    Parameters
    ----------
    image_size : (int, int)
        ``(width, height)`` in pixels.
    intrinsics : Intrinsics
    cameras : tuple of Camera
        In the order the views are given.
    reference : int
        Index of the reference camera (whose disparity map is produced).
    stereo_pair : (int, int)
        ``(reference, partner)``; the partner lies to the right of the reference
        along x; its distance is the baseline of the disparity convention.
    image_encoding : {"srgb", "linear"}
        How 8-bit images encode intensity.
    light_position_m : (float, float, float) or None
        The (first) light in the array frame, metres; what single-light code reads.
    lights : tuple of RigLight
        Every known light (position, optional radius and name); the first is the one
        ``light_position_m`` and :attr:`light` give. Either field may be given: a
        position alone makes one point light, lights alone set the position. Given
        together, the position must be the first light's.

    Examples
    --------
    >>> rig = CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, fy=600.0, cx=319.5, cy=239.5,
    ...                      image_size=(640, 480))
    >>> rig.n_cameras, rig.reference, rig.stereo_pair, round(rig.baseline_m, 3)
    (9, 4, (4, 5), 0.085)
    >>> rig.project([0.0, 0.0, 2.0]).tolist()
    [319.5, 239.5]
    """

    image_size: tuple[int, int]
    intrinsics: Intrinsics
    cameras: tuple[Camera, ...]
    reference: int = 0
    stereo_pair: tuple[int, int] = (0, 1)
    image_encoding: str = "srgb"
    light_position_m: tuple[float, float, float] | None = None
    lights: tuple[RigLight, ...] = ()
    _centers: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        size = self.image_size
        if (
            not isinstance(size, (tuple, list))
            or len(size) != 2
            or not all(
                isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s > 0 for s in size
            )
        ):
            raise RigError(
                f"image_size: expected [width, height] as two positive integers, got {size!r}"
            )
        object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))
        width, height = self.image_size
        if width * height > MAX_IMAGE_PIXELS:
            raise RigError(
                f"image_size: expected at most {MAX_IMAGE_PIXELS} pixels (the image pixel "
                f"limit), got {width}x{height} = {width * height}"
            )
        if not isinstance(self.intrinsics, Intrinsics):
            raise RigError(
                f"intrinsics: expected an Intrinsics, got {type(self.intrinsics).__name__}"
            )
        for name, extent in (("cx", width), ("cy", height)):
            value = getattr(self.intrinsics, name)
            lo, hi = -MAX_PRINCIPAL_OFFSET * extent, (1.0 + MAX_PRINCIPAL_OFFSET) * extent
            if not lo <= value <= hi:
                raise RigError(
                    f"intrinsics.{name}: expected a principal point within "
                    f"{MAX_PRINCIPAL_OFFSET:g} image sizes of the {width}x{height} image "
                    f"([{lo:g}, {hi:g}] px), got {value:g}"
                )
        cams = tuple(self.cameras)
        if len(cams) < 2:
            raise RigError(f"cameras: expected at least 2 cameras, got {len(cams)}")
        for i, c in enumerate(cams):
            if not isinstance(c, Camera):
                raise RigError(
                    f"cameras[{i}]: expected a Camera(name, center_m), got {type(c).__name__}"
                )
            if not isinstance(c.name, str) or not c.name:
                raise RigError(f"cameras[{i}].name: expected a non-empty string, got {c.name!r}")
        # Centres as tuples of floats keep the rig hashable, comparable and JSON-serialisable.
        cams = tuple(
            Camera(c.name, _vector3(c.center_m, f"cameras[{i}].center")) for i, c in enumerate(cams)
        )
        names = [c.name for c in cams]
        if len(set(names)) != len(names):
            raise RigError(f"cameras: expected unique names, got {names}")
        object.__setattr__(self, "cameras", cams)
        n = len(cams)
        ref = self.reference
        if isinstance(ref, bool) or not isinstance(ref, (int, np.integer)) or not 0 <= ref < n:
            raise RigError(f"reference: expected a camera index in [0, {n - 1}], got {ref!r}")
        object.__setattr__(self, "reference", int(ref))
        if not isinstance(self.stereo_pair, (tuple, list)):
            raise RigError(
                f"stereo_pair: expected two camera indices in [0, {n - 1}], "
                f"got {self.stereo_pair!r}"
            )
        pair = tuple(self.stereo_pair)
        if len(pair) != 2 or not all(
            isinstance(i, (int, np.integer)) and not isinstance(i, bool) and 0 <= i < n
            for i in pair
        ):
            raise RigError(
                f"stereo_pair: expected two camera indices in [0, {n - 1}], "
                f"got {self.stereo_pair!r}"
            )
        pair = (int(pair[0]), int(pair[1]))
        if pair[0] != self.reference:
            raise RigError(
                f"stereo_pair: expected the reference camera {self.reference} first, "
                f"got {list(pair)}"
            )
        object.__setattr__(self, "stereo_pair", pair)
        centers = np.array(
            [_vector3(c.center_m, f"cameras[{i}].center") for i, c in enumerate(cams)]
        )
        z0 = centers[self.reference, 2]
        off = np.abs(centers[:, 2] - z0)
        if off.max() > _COPLANAR_TOL_M:
            bad = int(np.argmax(off))
            raise RigError(
                f"cameras[{bad}].center: expected z = {z0:g} m like the reference camera "
                f"(a rectified array), got z = {centers[bad, 2]:g} m"
            )
        d = centers[pair[1]] - centers[pair[0]]
        if d[0] <= 0 or abs(d[1]) > _COPLANAR_TOL_M:
            raise RigError(
                f"stereo_pair: expected the partner camera {pair[1]} to lie to the right of the "
                f"reference along x (dx > 0, dy = 0), got dx = {d[0]:g} m, dy = {d[1]:g} m"
            )
        if d[0] < MIN_BASELINE_M:
            raise RigError(
                f"stereo_pair: expected a baseline of at least {MIN_BASELINE_M:g} m, got "
                f"{d[0]:g} m"
            )
        if self.image_encoding not in IMAGE_ENCODINGS:
            raise RigError(
                f"image_encoding: expected one of {list(IMAGE_ENCODINGS)}, "
                f"got {self.image_encoding!r}"
            )
        lights = _check_lights(self.lights, LightError)
        if self.light_position_m is not None:
            position = _vector3(self.light_position_m, "light.position", LightError)
            if not lights:
                lights = (RigLight(position),)
            elif lights[0].position_m != position:
                raise LightError(
                    f"light_position_m: expected the first light's position "
                    f"{list(lights[0].position_m)} (or None), got {list(position)}"
                )
            object.__setattr__(self, "light_position_m", position)
        elif lights:
            object.__setattr__(self, "light_position_m", lights[0].position_m)
        object.__setattr__(self, "lights", lights)
        centers.setflags(write=False)
        object.__setattr__(self, "_centers", centers)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def grid(
        cls,
        rows: int,
        cols: int,
        baseline_m: float,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        image_size: tuple[int, int] = (640, 480),
        *,
        focal_length_mm: float | None = None,
        pixel_size_um: float | None = None,
        light_position_m: Any = None,
        image_encoding: str = "srgb",
        lights: Any = None,
    ) -> CameraRig:
        """Build a ``rows x cols`` array with equal horizontal and vertical baselines.

        Cameras are numbered row by row, top-left first (``cam0`` ...). The reference is
        the centre camera (for an even count, the one left of/above the centre), at the
        origin of the array frame; its stereo partner is its right neighbour. The
        paper's array is ``grid(3, 3, baseline_m=0.085, ...)``.

        Either ``fx`` (and optionally ``fy``) or ``focal_length_mm`` with
        ``pixel_size_um`` gives the focal length; ``cx, cy`` default to the image centre.
        """
        for name, value in (("rows", rows), ("cols", cols)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise RigError(f"{name}: expected a positive integer, got {value!r}")
        if cols < 2:
            raise RigError(
                f"cols: expected at least 2 columns (a stereo partner to the right), got {cols}"
            )
        baseline_m = _number(baseline_m, "baseline_m", positive=True)
        intr = _make_intrinsics(fx, fy, cx, cy, image_size, focal_length_mm, pixel_size_um)
        r0, c0 = (rows - 1) // 2, (cols - 1) // 2
        cameras = tuple(
            Camera(f"cam{r * cols + c}", ((c - c0) * baseline_m, (r - r0) * baseline_m, 0.0))
            for r in range(rows)
            for c in range(cols)
        )
        ref = r0 * cols + c0
        return cls(
            tuple(image_size), intr, cameras, ref, (ref, ref + 1), image_encoding, light_position_m,
            _as_lights(lights),
        )

    @classmethod
    def stereo(
        cls,
        baseline_m: float,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        image_size: tuple[int, int] = (640, 480),
        *,
        focal_length_mm: float | None = None,
        pixel_size_um: float | None = None,
        light_position_m: Any = None,
        image_encoding: str = "srgb",
        names: tuple[str, str] = ("left", "right"),
        lights: Any = None,
    ) -> CameraRig:
        """Build a rectified two-camera rig: reference (left) at the origin, partner at ``+x``."""
        baseline_m = _number(baseline_m, "baseline_m", positive=True)
        intr = _make_intrinsics(fx, fy, cx, cy, image_size, focal_length_mm, pixel_size_um)
        cameras = (Camera(names[0], (0.0, 0.0, 0.0)), Camera(names[1], (baseline_m, 0.0, 0.0)))
        return cls(tuple(image_size), intr, cameras, 0, (0, 1), image_encoding, light_position_m,
                   _as_lights(lights))

    # ------------------------------------------------------------------ properties
    @property
    def n_cameras(self) -> int:
        """Number of cameras."""
        return len(self.cameras)

    @property
    def centers_m(self) -> np.ndarray:
        """Camera centres in the array frame, ``(N, 3)`` float64, metres (read-only)."""
        return self._centers

    @property
    def reference_center_m(self) -> np.ndarray:
        """Centre of the reference camera, ``(3,)``."""
        return self._centers[self.reference]

    @property
    def baseline_m(self) -> float:
        """Baseline of the stereo pair in metres."""
        a, b = self.stereo_pair
        return float(self._centers[b, 0] - self._centers[a, 0])

    @property
    def width(self) -> int:
        """Image width in pixels."""
        return self.image_size[0]

    @property
    def height(self) -> int:
        """Image height in pixels."""
        return self.image_size[1]

    @property
    def camera_names(self) -> list[str]:
        """Camera names in order."""
        return [c.name for c in self.cameras]

    @property
    def light(self) -> np.ndarray | None:
        """The (first) light's position as ``(3,)`` float64, or None."""
        return None if self.light_position_m is None else np.array(self.light_position_m)

    @property
    def light_positions_m(self) -> np.ndarray:
        """Every light's position, ``(L, 3)`` float64, metres (``(0, 3)`` without lights)."""
        return np.array([light.position_m for light in self.lights]).reshape(-1, 3)

    # ------------------------------------------------------------------ geometry helpers
    def project(self, points_m: Any, camera: int | None = None) -> np.ndarray:
        """Project 3D points (array frame, metres) into a camera's image.

        Parameters
        ----------
        points_m : array_like, (..., 3)
        camera : int, optional
            Camera index; the reference by default.

        Returns
        -------
        numpy.ndarray, (..., 2)
            Pixel coordinates ``(u, v)``; points at or behind the camera give NaN.
        """
        p = np.asarray(points_m, dtype=np.float64)
        c = self._centers[self.reference if camera is None else camera]
        rel = p - c
        k = self.intrinsics
        z = rel[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(z > 0, k.fx * rel[..., 0] / z + k.cx, np.nan)
            v = np.where(z > 0, k.fy * rel[..., 1] / z + k.cy, np.nan)
        return np.stack([u, v], axis=-1)

    def rays(self, uv: Any) -> np.ndarray:
        """Ray directions ``((u - cx)/fx, (v - cy)/fy, 1)`` for pixels ``(..., 2)``."""
        uv = np.asarray(uv, dtype=np.float64)
        k = self.intrinsics
        return np.stack(
            [(uv[..., 0] - k.cx) / k.fx, (uv[..., 1] - k.cy) / k.fy, np.ones(uv.shape[:-1])],
            axis=-1,
        )

    def backproject(self, uv: Any, depth_m: Any, camera: int | None = None) -> np.ndarray:
        """3D points (array frame) at depth ``depth_m`` along the pixel rays of a camera.

        Parameters
        ----------
        uv : array_like, (..., 2)
            Pixel coordinates.
        depth_m : array_like, (...)
            Depth along the camera's z axis, metres.
        camera : int, optional
            Camera index; the reference by default.
        """
        c = self._centers[self.reference if camera is None else camera]
        return c + self.rays(uv) * np.asarray(depth_m, dtype=np.float64)[..., None]

    def depth_to_disparity(self, depth_m: Any) -> np.ndarray:
        """Disparity in pixels of the stereo pair, ``fx * B / z`` (NaN where z <= 0)."""
        z = np.asarray(depth_m, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(z > 0, self.intrinsics.fx * self.baseline_m / z, np.nan)

    def disparity_to_depth(self, disparity_px: Any) -> np.ndarray:
        """Depth in metres from stereo-pair disparity, ``fx * B / d`` (NaN where d <= 0)."""
        d = np.asarray(disparity_px, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(d > 0, self.intrinsics.fx * self.baseline_m / d, np.nan)

    # ------------------------------------------------------------------ derived rigs
    def with_light(self, light_position_m: Any) -> CameraRig:
        """Return a copy of the rig with one point light at the given position (or none)."""
        if light_position_m is None:
            return replace(self, light_position_m=None, lights=())
        position = _vector3(light_position_m, "light_position_m", LightError)
        return replace(self, light_position_m=position, lights=(RigLight(position),))

    def with_lights(self, lights: Any) -> CameraRig:
        """Return a copy of the rig with these lights (RigLight or ``(3,)`` positions, metres).

        Examples
        --------
        >>> rig = CameraRig.stereo(0.1, fx=500.0)
        >>> lit = rig.with_lights([(0.3, -0.2, 0.0), RigLight((-0.3, -0.2, 0.0), name="b")])
        >>> len(lit.lights), lit.light.tolist(), lit.lights[1].name
        (2, [0.3, -0.2, 0.0], 'b')
        """
        lights = _as_lights(lights)
        return replace(self, light_position_m=lights[0].position_m if lights else None,
                       lights=lights)

    def scaled(self, factor: float) -> CameraRig:
        """Return the rig for images resized by ``factor`` (intrinsics follow the pixel grid)."""
        factor = _number(factor, "factor", positive=True)
        w, h = self.image_size
        new_size = (max(1, round(w * factor)), max(1, round(h * factor)))
        sx, sy = new_size[0] / w, new_size[1] / h
        k = self.intrinsics
        # Pixel centres at integer coordinates: x_new + 0.5 = (x_old + 0.5) * s.
        intr = Intrinsics(k.fx * sx, k.fy * sy, (k.cx + 0.5) * sx - 0.5, (k.cy + 0.5) * sy - 0.5)
        return replace(self, image_size=new_size, intrinsics=intr)

    def subset(self, indices: Any) -> CameraRig:
        """Return a rig of some of the cameras; the reference and its partner must be kept."""
        n = self.n_cameras
        idx = list(indices)
        # Negative indices would silently wrap to other cameras.
        if not all(
            isinstance(i, (int, np.integer)) and not isinstance(i, bool) and 0 <= i < n for i in idx
        ):
            raise RigError(f"indices: expected camera indices in [0, {n - 1}], got {idx!r}")
        idx = [int(i) for i in idx]
        for must in self.stereo_pair:
            if must not in idx:
                raise RigError(
                    f"indices: expected the stereo pair {list(self.stereo_pair)} to be kept, "
                    f"got {idx}"
                )
        cams = tuple(self.cameras[i] for i in idx)
        return replace(
            self,
            cameras=cams,
            reference=idx.index(self.reference),
            stereo_pair=(idx.index(self.stereo_pair[0]), idx.index(self.stereo_pair[1])),
        )

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """Return the ``rig.json`` content as a dict (DESIGN §5)."""
        k = self.intrinsics
        out: dict[str, Any] = {
            "format": RIG_FORMAT,
            "image_size": list(self.image_size),
            "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
            "cameras": [{"name": c.name, "center": list(c.center_m)} for c in self.cameras],
            "reference": self.reference,
            "stereo_pair": list(self.stereo_pair),
            "image_encoding": self.image_encoding,
        }
        # One light keeps the single-light form, so older files round-trip byte for byte.
        if len(self.lights) == 1:
            out["light"] = self.lights[0].to_dict()
        elif self.lights:
            out["light"] = [light.to_dict() for light in self.lights]
        return out

    @classmethod
    def from_dict(cls, data: Any) -> CameraRig:
        """Build a rig from a ``rig.json`` dict, validating every field.

        Raises
        ------
        RigError
            Unknown or missing keys, wrong types, non-positive focal lengths, indices out
            of range, or a stereo partner not to the right of the reference.
        """
        _check_keys(
            data,
            {
                "format",
                "image_size",
                "intrinsics",
                "cameras",
                "reference",
                "stereo_pair",
                "image_encoding",
                "light",
            },
            {"format", "image_size", "intrinsics", "cameras", "reference", "stereo_pair"},
            "rig",
        )
        if data["format"] != RIG_FORMAT:
            raise RigError(f"format: expected {RIG_FORMAT!r}, got {data['format']!r}")
        intr_d = data["intrinsics"]
        if isinstance(intr_d, dict) and "focal_length_mm" in intr_d:
            _check_keys(
                intr_d,
                {"focal_length_mm", "pixel_size_um", "cx", "cy"},
                {"focal_length_mm", "pixel_size_um", "cx", "cy"},
                "intrinsics",
            )
            intr = Intrinsics.from_focal_length(
                intr_d["focal_length_mm"],
                intr_d["pixel_size_um"],
                _number(intr_d["cx"], "intrinsics.cx"),
                _number(intr_d["cy"], "intrinsics.cy"),
            )
        else:
            _check_keys(intr_d, {"fx", "fy", "cx", "cy"}, {"fx", "fy", "cx", "cy"}, "intrinsics")
            intr = Intrinsics(
                *(
                    _number(intr_d[key], f"intrinsics.{key}", positive=key in ("fx", "fy"))
                    for key in ("fx", "fy", "cx", "cy")
                )
            )
        cams_d = data["cameras"]
        if not isinstance(cams_d, list):
            raise RigError(
                f"cameras: expected a list of {{name, center}} objects, got {type(cams_d).__name__}"
            )
        cameras = []
        for i, c in enumerate(cams_d):
            _check_keys(c, {"name", "center"}, {"name", "center"}, f"cameras[{i}]")
            if not isinstance(c["name"], str) or not c["name"]:
                raise RigError(f"cameras[{i}].name: expected a non-empty string, got {c['name']!r}")
            cameras.append(Camera(c["name"], _vector3(c["center"], f"cameras[{i}].center")))
        size = data["image_size"]
        if not isinstance(size, list) or len(size) != 2:
            raise RigError(f"image_size: expected [width, height], got {size!r}")
        pair = data["stereo_pair"]
        if not isinstance(pair, list):
            raise RigError(f"stereo_pair: expected a list of two camera indices, got {pair!r}")
        lights = _lights_from_json(data.get("light"))
        return cls(
            tuple(size),
            intr,
            tuple(cameras),
            data["reference"],
            tuple(pair),
            data.get("image_encoding", "srgb"),
            None,
            lights,
        )

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """Serialise to JSON; write it to ``path`` if given. Returns the text."""
        return dump_json(self.to_dict(), path)

    @classmethod
    def from_json(cls, source: str | os.PathLike) -> CameraRig:
        """Read a rig from a ``rig.json`` path or from a JSON string.

        Errors in a file's content name the file (``path: field: expected X, got Y``).
        """
        data = load_json_source(source, "rig", RigError)
        is_path = isinstance(source, os.PathLike) or not str(source).lstrip().startswith("{")
        try:
            return cls.from_dict(data)
        except RigError as exc:
            if not is_path:
                raise
            raise RigError(f"{source}: {exc}") from None


def _as_lights(lights: Any) -> tuple[RigLight, ...]:
    """Lights given in code: None, RigLights and/or ``(3,)`` positions in metres."""
    if lights is None:
        return ()
    if isinstance(lights, RigLight):
        return (lights,)
    if isinstance(lights, np.ndarray):
        lights = list(lights.reshape(-1, 3)) if lights.size else []
    if not isinstance(lights, (tuple, list)):
        raise LightError(
            f"lights: expected a sequence of RigLight or (3,) positions, got "
            f"{type(lights).__name__}"
        )
    out = tuple(
        light if isinstance(light, RigLight)
        else RigLight(_vector3(light, f"lights[{i}]", LightError))
        for i, light in enumerate(lights)
    )
    return _check_lights(out, LightError)


def _lights_from_json(value: Any) -> tuple[RigLight, ...]:
    """Read the ``light`` entry of ``rig.json``: one object (one light) or a list of them."""
    if value is None:
        return ()
    if isinstance(value, dict):
        entries, names = [value], ["light"]
    elif isinstance(value, list):
        if not value:
            raise RigError("light: expected one light object or a non-empty list of them "
                           "(or no 'light' key), got []")
        if len(value) > MAX_LIGHTS:
            raise RigError(f"light: expected at most {MAX_LIGHTS} lights, got {len(value)}")
        entries, names = value, [f"light[{i}]" for i in range(len(value))]
    else:
        raise RigError(
            f"light: expected an object {{position, radius_m?, name?}} or a list of them, "
            f"got {type(value).__name__}"
        )
    lights = []
    for entry, where in zip(entries, names, strict=True):
        _check_keys(entry, {"position", "radius_m", "name"}, {"position"}, where)
        pos, radius, name = _light_fields(entry["position"], entry.get("radius_m"),
                                          entry.get("name"), where, RigError)
        lights.append(RigLight(pos, radius, name))
    return _check_lights(tuple(lights), RigError)


def _make_intrinsics(fx, fy, cx, cy, image_size, focal_length_mm, pixel_size_um) -> Intrinsics:
    if (
        not isinstance(image_size, (tuple, list))
        or len(image_size) != 2
        or not all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) for s in image_size)
    ):
        raise RigError(f"image_size: expected (width, height) as two integers, got {image_size!r}")
    w, h = image_size
    cx = (w - 1) / 2.0 if cx is None else cx
    cy = (h - 1) / 2.0 if cy is None else cy
    if focal_length_mm is not None or pixel_size_um is not None:
        if fx is not None or fy is not None:
            raise RigError(
                "focal length: expected either fx/fy or focal_length_mm with "
                "pixel_size_um, got both"
            )
        if focal_length_mm is None or pixel_size_um is None:
            raise RigError("focal length: expected both focal_length_mm and pixel_size_um")
        return Intrinsics.from_focal_length(focal_length_mm, pixel_size_um, cx, cy)
    if fx is None:
        raise RigError(
            "fx: expected a focal length in pixels (or focal_length_mm with "
            "pixel_size_um), got None"
        )
    return Intrinsics(fx, fx if fy is None else fy, cx, cy)


def project_points(rig: CameraRig, points_m: np.ndarray, cameras: Any) -> np.ndarray:
    """Project array-frame points ``(..., 3)``, each into its own camera, pixels ``(..., 2)``.

    ``cameras`` (int indices) broadcasts against the points' leading axes: ``(P, 3)``
    points with ``(P,)`` cameras, one ``(3,)`` point with ``(N,)`` cameras, or
    ``(K, 1, 3)`` points with ``(N,)`` cameras for every point in every camera.
    """
    rel = points_m - rig.centers_m[cameras]
    k = rig.intrinsics
    return np.stack(
        [k.fx * rel[..., 0] / rel[..., 2] + k.cx, k.fy * rel[..., 1] / rel[..., 2] + k.cy],
        axis=-1)
