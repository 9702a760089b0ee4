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
from .physics import (
    Physics,
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
    highlights_on_objects,
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
    relit,
    rig_lights,
)
from .shading import (
    LOBES,
    blinn_phong_exponent,
    disc_samples,
    fresnel_exact,
    ggx_ndf,
    ior_from_f0,
    schlick_fresnel,
    smith_g1_ggx,
    smith_g2_height_correlated,
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
    "highlights_on_objects",
    "relit",
    "rig_lights",
    "Physics",
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
    "fresnel_exact",
    "ior_from_f0",
    "smith_g2_height_correlated",
    "disc_samples",
    "blinn_phong_exponent",
    "widened_roughness",
    "specular_brdf",
]
