"""Datasets of rendered scene folders, and scenes to and from JSON."""

from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ..errors import SceneError
from ..geometry import CameraRig
from ..io import write_scene
from .physics import Physics
from .random_scenes import random_scene
from .render import render
from .scene import Light, Material, PlanarObject, Scene, check_rig, rig_lights

__all__ = [
    "default_rig",
    "render_dataset",
    "scene_to_dict",
    "scene_from_dict",
]

# ---------------------------------------------------------------------------------- datasets
def default_rig() -> CameraRig:
    """Return the paper's array: 3 x 3 cameras, 85 mm baselines, 640 x 480, fx = fy = 600."""
    return CameraRig.grid(3, 3, baseline_m=0.085, fx=600.0, fy=600.0, image_size=(640, 480))


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """Describe a scene as a JSON-serialisable dict (textures are only flagged)."""

    def obj_dict(o: PlanarObject) -> dict[str, Any]:
        return {
            "shape": o.shape,
            "center_m": list(o.center_m),
            "normal": list(o.normal),
            "size_m": list(o.size_m),
            "rotation_rad": o.rotation_rad,
            "vertices_m": None if o.vertices_m is None else [list(v) for v in o.vertices_m],
            "material": {
                "diffuse_rgb": list(o.material.diffuse_rgb),
                "specular": o.material.specular,
                "roughness": o.material.roughness,
                "lobe": o.material.lobe,
                "f0": o.material.f0,
                "ior": o.material.ior,
                "extinction": o.material.extinction,
            },
            "textured": o.texture is not None,
        }

    def light_dict(light: Light) -> dict[str, Any]:
        return {
            "position_m": list(light.position_m),
            "radius_m": light.radius_m,
            "color_rgb": list(light.color_rgb),
            "intensity": light.intensity,
        }

    out = {
        "objects": [obj_dict(o) for o in scene.objects],
        "light": light_dict(scene.light),
        "ambient": scene.ambient,
        "background": scene.background,
        "background_seed": scene.background_seed,
        "exposure": scene.exposure,
        "noise_std": scene.noise_std,
    }
    # "light" stays the first light, as single-light readers expect; "lights" lists all.
    if len(scene.lights) > 1:
        out["lights"] = [light_dict(light) for light in scene.lights]
    return out


def scene_from_dict(data: Any) -> Scene:
    """Rebuild a scene from :func:`scene_to_dict` output (object textures are not stored).

    Raises
    ------
    SceneError
        Missing keys or values of the wrong kind.

    Examples
    --------
    >>> plate = PlanarObject("ellipse", (0.0, 0.0, 1.0), (0.1, 0.0, -1.0), (0.2, 0.1))
    >>> scene = Scene((plate,), Light((0.3, 0.0, 0.0)))
    >>> scene_from_dict(scene_to_dict(scene)) == scene
    True
    """
    try:
        objects = tuple(
            PlanarObject(
                shape=o["shape"],
                center_m=tuple(o["center_m"]),
                normal=tuple(o["normal"]),
                size_m=tuple(o["size_m"]),
                rotation_rad=o["rotation_rad"],
                vertices_m=None if o["vertices_m"] is None else tuple(map(tuple, o["vertices_m"])),
                material=Material(
                    **{**o["material"], "diffuse_rgb": tuple(o["material"]["diffuse_rgb"])}
                ),
            )
            for o in data["objects"]
        )
        def light_from(entry: dict) -> Light:
            return Light(tuple(entry["position_m"]), entry["radius_m"],
                         tuple(entry["color_rgb"]), entry["intensity"])

        lights = tuple(light_from(e) for e in data.get("lights", [data["light"]]))
        return Scene(
            objects,
            light_from(data["light"]),
            lights=lights,
            ambient=data["ambient"],
            background=data["background"],
            background_seed=data["background_seed"],
            exposure=data["exposure"],
            noise_std=data["noise_std"],
        )
    except (KeyError, TypeError, AttributeError) as exc:
        raise SceneError(
            f"scene: expected a dict as written by scene_to_dict, got one that fails with "
            f"{type(exc).__name__}: {exc}"
        ) from None


def render_dataset(
    out_dir: str | Path,
    *,
    n_scenes: int,
    seed: int = 0,
    rig: CameraRig | None = None,
    background: str = "none",
    n_objects: int = 1,
    supersample: int = 1,
    physics: Physics | None = None,
    progress: bool = True,
    overwrite: bool = False,
    **scene_options: Any,
) -> list[Path]:
    """Render ``n_scenes`` random scenes into scene folders ``scene_0000``, ... (DESIGN §5).

    Each folder holds the views, ``rig.json`` with the scene's lights, ``mask.png``
    (instance labels), ``gt_disparity.pfm`` and ``scene.json`` (the scene description,
    virtual lights and highlight centres; with several lights also, per light, the
    virtual lights, highlight centres and whether each highlight is on its object in
    each view: ``lights_ground_truth``).

    Parameters
    ----------
    out_dir : str or path-like
        Created if needed.
    n_scenes : int
    seed : int
        Dataset seed; scene ``i`` uses a seed derived from ``(seed, i)``.
    rig : CameraRig, optional
        :func:`default_rig` by default; its light is replaced by each scene's.
    background, n_objects, **scene_options
        Passed to :func:`random_scene`.
    supersample : int
        Passed to :func:`render`.
    physics : Physics, optional
        Passed to :func:`render` (the refinement's own model by default;
        ``Physics.faithful()`` for what it does not assume); recorded in ``scene.json``.
    progress : bool
        Show a progress bar.
    overwrite : bool
        Replace the scene folders (``scene_NNNN``) already in ``out_dir``. Without it an
        ``out_dir`` holding scene folders is refused: rendering would overwrite some and
        leave others beside the new ones, where an evaluation would mix them in.

    Returns
    -------
    list of pathlib.Path
        The scene folders.

    Raises
    ------
    SceneError
        Invalid options, or scene folders in ``out_dir`` without ``overwrite``.
    """
    if isinstance(n_scenes, bool) or not isinstance(n_scenes, (int, np.integer)) or n_scenes < 1:
        raise SceneError(f"n_scenes: expected a positive integer, got {n_scenes!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SceneError(f"seed: expected a non-negative integer, got {seed!r}")
    rig = default_rig() if rig is None else check_rig(rig)
    out = Path(out_dir)
    existing = sorted(p for p in out.glob("scene_*") if p.is_dir()) if out.is_dir() else []
    if existing and not overwrite:
        raise SceneError(
            f"{out}: expected a folder without scene folders, got {len(existing)} "
            f"({', '.join(p.name for p in existing[:3])}{', ...' if len(existing) > 3 else ''}) "
            f"with their images, rig.json and ground truth; rendering would overwrite or mix "
            f"with them: pass overwrite=True (render --force) to replace them")
    # Replacing a dataset renders into a hidden staging folder first and swaps the scene
    # folders in at the end: a run killed while rendering leaves the old dataset whole.
    staging = None
    if existing:
        staging = Path(tempfile.mkdtemp(prefix=".render-", dir=out))
    target = out if staging is None else staging
    folders: list[Path] = []
    try:
        for i in tqdm(range(n_scenes), desc="render", unit="scene", disable=not progress):
            scene_seed = int(np.random.SeedSequence([seed, i]).generate_state(1)[0])
            scene = random_scene(
                scene_seed, rig, n_objects=n_objects, background=background, **scene_options
            )
            scene_rig = rig.with_lights(rig_lights(scene))
            result = render(scene, scene_rig, supersample=supersample, physics=physics)
            metadata = {
                "generator": "srde_fusion.synthetic.random_scene",
                "seed": scene_seed,
                "physics": dataclasses.asdict(physics or Physics()),
                "supersample": supersample,
                "scene": scene_to_dict(scene),
                "virtual_lights_m": result.virtual_lights_m.tolist(),
                "highlight_uv": np.nan_to_num(result.highlight_uv, nan=-1.0).tolist(),
                "planes": [{"normal": list(p.normal), "offset_m": p.offset_m}
                           for p in result.planes],
            }
            if len(scene.lights) > 1:
                metadata["lights_ground_truth"] = {
                    "virtual_lights_m": result.virtual_lights_by_light_m.tolist(),
                    "highlight_uv": np.nan_to_num(result.highlight_uv_by_light,
                                                  nan=-1.0).tolist(),
                    "highlight_on_object": result.highlight_on_object.tolist(),
                }
            folders.append(
                write_scene(
                    target / f"scene_{i:04d}",
                    result.views,
                    scene_rig,
                    mask=result.instance_mask,
                    gt_disparity=result.disparity_px,
                    metadata=metadata,
                )
            )
    except BaseException:
        if staging is not None:  # the old dataset is untouched; drop the half-made one
            shutil.rmtree(staging, ignore_errors=True)
        raise
    if staging is not None:
        folders = _swap_in(staging, out, folders, existing)
    return folders


def _swap_in(staging: Path, out: Path, new: list[Path], old: list[Path]) -> list[Path]:
    """Move freshly rendered scene folders from ``staging`` into ``out``, replacing ``old``.

    Each old folder is first moved aside into the staging folder and the new one renamed
    into its place (two renames on one file system), so at any moment a scene folder is
    either the old or the new one; old folders with no new counterpart are removed (an
    evaluation would otherwise mix them in).
    """
    aside = staging / ".replaced"
    aside.mkdir()
    placed = []
    for folder in new:
        final = out / folder.name
        if final.exists():
            os.replace(final, aside / folder.name)
        os.replace(folder, final)
        placed.append(final)
    for folder in old:
        if folder.exists() and folder not in placed:
            os.replace(folder, aside / folder.name)
    shutil.rmtree(staging)
    return placed
