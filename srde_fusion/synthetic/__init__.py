"""Synthetic scenes with exact ground truth: shading, rendering, datasets.

Imports ``geometry``, ``imaging``, ``calibration`` (printed plates) and ``io``.
"""

from __future__ import annotations

from .scenes import (
    BACKGROUNDS,
    SHAPES,
    Light,
    Material,
    PlanarObject,
    Rendering,
    Scene,
    SceneError,
    default_rig,
    random_scene,
    render,
    render_dataset,
    scene_from_dict,
    scene_to_dict,
)
from .shading import (
    LOBES,
    blinn_phong_exponent,
    ggx_ndf,
    schlick_fresnel,
    smith_g1_ggx,
    specular_brdf,
    widened_roughness,
)

__all__ = [
    "SceneError",
    "Material",
    "PlanarObject",
    "Light",
    "Scene",
    "Rendering",
    "render",
    "random_scene",
    "default_rig",
    "render_dataset",
    "scene_to_dict",
    "scene_from_dict",
    "SHAPES",
    "BACKGROUNDS",
    "LOBES",
    "ggx_ndf",
    "smith_g1_ggx",
    "schlick_fresnel",
    "blinn_phong_exponent",
    "widened_roughness",
    "specular_brdf",
]
