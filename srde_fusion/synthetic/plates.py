"""Rendered captures of the light-calibration plate, for tests and benchmarks.

``plate_scene`` poses an ArUco plate (:class:`~srde_fusion.calibration.Board`) so that the
light's highlight falls on its free centre for the reference camera (with several lights,
the highlight of their mean position: the highlights then lie around the centre), and
returns a :class:`~srde_fusion.synthetic.Scene` the renderer can draw.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .._checks import check_point3
from ..calibration import (
    Board,
    render_board_image,
)
from ..errors import LightError
from ..geometry import MAX_LIGHTS, CameraRig
from .scene import Light, Material, PlanarObject, Scene

__all__ = [
    "highlight_normal",
    "plate_scene",
]

# ---------------------------------------------------------------------- synthetic plates
def highlight_normal(point_m: Any, light_m: Any, camera_m: Any = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Return the plate normal that puts the highlight at ``point_m`` seen from ``camera_m``.

    The mirror normal is the half vector between the directions to the light and to
    the camera.

    Returns
    -------
    numpy.ndarray, (3,)
        Unit normal, pointing towards the camera side.

    Examples
    --------
    >>> highlight_normal([0, 0, 1.0], [0, -1.0, 1.0], [0, 0, 0]).round(4).tolist()
    [0.0, -0.7071, -0.7071]
    """
    p = check_point3(point_m, "point_m")
    to_light = check_point3(light_m, "light_m") - p
    to_camera = check_point3(camera_m, "camera_m") - p
    half = to_light / np.linalg.norm(to_light) + to_camera / np.linalg.norm(to_camera)
    norm = np.linalg.norm(half)
    if norm < 1e-9:
        raise LightError(
            "light_m: expected a light not exactly behind the point as seen from the "
            "camera, got opposite directions"
        )
    return half / norm


def _light_positions(value: Any) -> np.ndarray:
    """``(L, 3)`` light positions from one ``(3,)`` position or a list of them."""
    array = np.asarray(value, dtype=object)
    if array.ndim == 2:
        if not 1 <= len(array) <= MAX_LIGHTS:
            raise LightError(f"light_position_m: expected 1 to {MAX_LIGHTS} lights, got "
                             f"{len(array)}")
        return np.array([check_point3(p, f"light_position_m[{i}]") for i, p in enumerate(value)])
    return check_point3(value, "light_position_m")[None]


#: Linear level of the white plate (diffuse, at its centre) that ``plate_scene`` exposes for.
PLATE_WHITE_LEVEL = 0.3


def plate_scene(
    board: Board,
    rig: CameraRig,
    light_position_m: Any,
    *,
    center_m: Any,
    normal: Any = None,
    rotation_rad: float = 0.0,
    texture_dpi: float = 100.0,
    albedo: float = 0.8,
    roughness: float = 0.005,
    light_radius_m: float = 0.003,
    ambient: float = 0.05,
    noise_std: float = 0.0,
):
    """Build a synthetic scene of the calibration plate lit by a small light.

    The plate is a glossy white rectangle of ``board.plate_size_m`` carrying the
    board's markers as texture; its local axes are those of
    :meth:`PlatePose.from_center_normal` with the same arguments, which is therefore
    its true pose. The exposure puts the white plate at a fixed linear level, so the
    highlight clips as on a real camera.

    Parameters
    ----------
    board : Board
    rig : CameraRig
    light_position_m : array_like, (3,) or (L, 3)
        The light, or several lights (one highlight each), array frame, metres.
    center_m : array_like, (3,)
        Plate centre, array frame, metres.
    normal : array_like, (3,), optional
        Normal of the printed side; by default the one that puts the highlight at the
        plate centre as seen from the reference camera (:func:`highlight_normal`); with
        several lights, the highlight of a light at their mean position.
    rotation_rad : float
        In-plane rotation of the plate.
    texture_dpi : float
        Resolution of the marker texture.
    albedo : float
        Diffuse albedo of the white plate, in [0, 1].
    roughness : float
        Specular lobe width (GGX alpha).
    light_radius_m : float
        Radius of the spherical light (of each light).
    ambient : float
        Ambient radiance per unit albedo, relative to the plate's direct light.
    noise_std : float
        Sensor noise, linear units.

    Returns
    -------
    srde_fusion.synthetic.Scene
    """
    positions = _light_positions(light_position_m)
    light = positions.mean(axis=0) if len(positions) > 1 else positions[0]
    center = check_point3(center_m, "center_m")
    n = (
        highlight_normal(center, light, rig.reference_center_m)
        if normal is None
        else check_point3(normal, "normal")
    )
    texture = render_board_image(board, texture_dpi)
    plate = PlanarObject(
        "rectangle",
        tuple(center),
        tuple(n),
        board.plate_size_m,
        rotation_rad=rotation_rad,
        material=Material(diffuse_rgb=(albedo,) * 3, roughness=roughness),
        texture=texture,
    )
    direct = 0.0
    for position in positions:
        to_light = position - center
        dist2 = float(to_light @ to_light)
        cos_l = abs(float(to_light @ np.asarray(plate.normal))) / math.sqrt(dist2)
        # Diffuse radiance of the white plate per unit exposure (the renderer's Lambert term).
        direct += albedo / math.pi * cos_l / dist2
    exposure = PLATE_WHITE_LEVEL / (direct * (1.0 + ambient))
    lights = tuple(Light(tuple(p), radius_m=light_radius_m) for p in positions)
    return Scene(
        (plate,),
        lights=lights,
        ambient=ambient * direct,
        exposure=exposure,
        noise_std=noise_std,
    )
