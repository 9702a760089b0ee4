"""Synthetic scenes with exact ground truth: shading, rendering, datasets.

Imports ``geometry``, ``imaging``, ``calibration`` (printed plates) and ``io``.
"""

from __future__ import annotations

from .datasets import (
    default_rig,
    render_dataset,
    scene_from_dict,
    scene_to_dict,
)
from .plates import (
    highlight_normal,
    plate_scene,
)
from .random_scenes import (
    RandomSceneConfig,
    random_scene,
)
from .render import (
    render,
)
from .scene import (
    BACKGROUNDS,
    SHAPES,
    Light,
    Material,
    PlanarObject,
    Rendering,
    Scene,
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
    "default_rig",
    "render_dataset",
    "scene_to_dict",
    "scene_from_dict",
    "highlight_normal",
    "plate_scene",
    "RandomSceneConfig",
    "random_scene",
    "render",
    "Material",
    "PlanarObject",
    "Light",
    "Scene",
    "Rendering",
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
