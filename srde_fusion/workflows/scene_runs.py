"""Scene folders in, result folders out: the demo, fusion of one scene, SRDE alone.

Each workflow reads a scene folder (or renders one), runs the stages -- backbone, mask
stage, SRDE, fusion -- and writes the disparity maps, the source map, a JSON report and a
figure. They take a backbone *callable*; turning a model file, preset or torch module into
one is the adapters' job (the command does it).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .._atomic import write_atomic
from .._json import json_safe
from ..errors import FileFormatError, SRDEError
from ..evaluation import (
    METHODS,
    TABLE_KEYS,
    colorize_disparity,
    comparison_figure,
    format_markdown_table,
    save_figure,
    score_fusion,
)
from ..fusion import FusionResult, HybridStereo, fuse, postprocess
from ..geometry import CameraRig
from ..io import (
    disparity_to_points,
    list_scenes,
    read_disparity,
    read_scene,
    write_disparity,
    write_image,
    write_mask,
    write_pfm,
    write_ply,
    write_scene,
)
from ..masks import HighlightSegmenter, resolve_masker
from ..srde import SRDE
from ..synthetic import default_rig, random_scene, render, scene_to_dict

_log = logging.getLogger(__name__)

__all__ = [
    "DemoResult",
    "SceneRun",
    "scores_table",
    "write_fusion_outputs",
    "run_demo",
    "fuse_scene",
    "srde_scene",
    "fuse_dataset",
    "DatasetRun",
    "DEMO_SEED",
    "DEMO_OBJECTS",
]

Backbone = Callable[[np.ndarray, np.ndarray], np.ndarray]

# What the demo's mask stage is, as reports name it.
_AUTO_MASKS = resolve_masker("auto").description

#: Seed of the demo scene: a textured room with two glossy objects.
DEMO_SEED = 7
#: Objects in the demo scene.
DEMO_OBJECTS = 2
#: File names written by :func:`write_fusion_outputs`.
FUSED_PFM = "fused_disparity.pfm"
FUSED_PNG = "fused_disparity.png"
BACKBONE_PFM = "backbone_disparity.pfm"
SRDE_PFM = "srde_disparity.pfm"
SOURCE_PNG = "source.png"
REPORT_JSON = "report.json"
FIGURE_PNG = "figure.png"
SRDE_PNG = "srde_disparity.png"
DEPTH_PFM = "depth.pfm"
POINTS_PLY = "points.ply"
COLOR_PNG = "disparity_color.png"
#: Every name :func:`write_fusion_outputs` may write; one left from an earlier run and not
#: written by this one is removed, so a folder never mixes two runs.
OUTPUT_FILES = (FUSED_PFM, FUSED_PNG, BACKBONE_PFM, SRDE_PFM, SRDE_PNG, SOURCE_PNG,
                REPORT_JSON, FIGURE_PNG, DEPTH_PFM, POINTS_PLY, COLOR_PNG)


@dataclass(frozen=True)
class SceneRun:
    """What a workflow produced for one scene.

    Attributes
    ----------
    fusion : FusionResult
        The fused map, source map and per-object reports.
    scores : dict or None
        ``scores[method][region]`` against ground truth (see
        :func:`~srde_fusion.evaluation.evaluate.score_fusion`), None without ground truth.
    files : dict of str -> pathlib.Path
        Every file written, by role.
    notes : tuple of str
        Anything the caller should know (e.g. a file that could not be written).
    masks : str
        Which mask stage found the objects, and what was done to user masks (see
        :func:`~srde_fusion.masks.resolve_masker`).
    """

    fusion: FusionResult
    scores: dict | None
    files: dict
    notes: tuple[str, ...] = ()
    masks: str = ""

    def table(self) -> str:
        """Return markdown tables of the scores (backbone, SRDE, fused; full and objects)."""
        return scores_table(self.scores) if self.scores is not None else ""


@dataclass(frozen=True)
class DemoResult(SceneRun):
    """A :class:`SceneRun` of the demo, with the folder of the rendered scene."""

    scene_dir: Path | None = None


def scores_table(scores: dict) -> str:
    """Return markdown tables of ``scores[method][region]`` (full scene, then objects)."""
    parts = []
    for region, title in (("full", "Full scene"), ("masked", "Objects (masked)")):
        rows = {m: scores[m][region] for m in METHODS}
        parts.append(f"### {title}\n\n" + format_markdown_table(rows, TABLE_KEYS))
    return "\n".join(parts)



def write_fusion_outputs(out_dir: str | os.PathLike, result: FusionResult,
                         image: np.ndarray, *, gt_disparity: np.ndarray | None = None,
                         region: np.ndarray | None = None, extra: dict | None = None,
                         title: str | None = None, srde_only: bool = False,
                         rig: CameraRig | None = None) -> SceneRun:
    """Write a fusion result: disparity maps, source map, JSON report and figure.

    Files: ``fused_disparity.pfm`` (invalid = inf) and ``fused_disparity.png`` (KITTI
    16-bit, value / 256, 0 = invalid), ``backbone_disparity.pfm``, ``srde_disparity.pfm``,
    ``source.png`` (8-bit: 0 = backbone, k = object k's SRDE plane), ``report.json``
    (per-object decisions and, with ground truth, the scores) and ``figure.png``. With
    ``srde_only`` (SRDE run without a backbone) the disparity files are
    ``srde_disparity.pfm`` and ``srde_disparity.png`` only. Files of these names left in
    ``out_dir`` by an earlier run and not written by this one are removed (and a note
    says so); ``report.json``, written last, lists this run's files.

    Parameters
    ----------
    out_dir : path
        Created if needed.
    result : FusionResult
    image : numpy.ndarray, (H, W, 3) uint8
        The reference view (for the figure).
    gt_disparity : numpy.ndarray, (H, W), float, optional
        Ground truth; adds scores to the report and error maps to the figure.
    region : numpy.ndarray, (H, W), bool, optional
        The objects for the masked scores (the ground-truth masks where known).
    extra : dict, optional
        More JSON-serialisable entries for the report.
    title : str, optional
        Figure title.
    srde_only : bool
        Write and draw SRDE's map only.
    rig : CameraRig, optional
        With the rig, the map is also written as ``depth.pfm`` (reference camera z,
        metres, inf = invalid), ``points.ply`` (the valid pixels as 3D points in the
        array frame, coloured from the reference view) and ``disparity_color.png``.

    Returns
    -------
    SceneRun
    """
    out = Path(out_dir)
    _log.info("writing the results into %s", out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FileFormatError(f"{out}: could not create the output folder: {exc}") from None
    files: dict[str, Path] = {}
    notes: list[str] = []
    main, main_pfm = ("srde", SRDE_PFM) if srde_only else ("fused", FUSED_PFM)
    main_png = main_pfm.replace(".pfm", ".png")
    files[f"{main}_pfm"] = write_disparity(out / main_pfm, result.disparity)
    try:
        files[f"{main}_png"] = write_disparity(out / main_png, result.disparity)
    except FileFormatError as exc:  # beyond the 16-bit format's range
        notes.append(f"{main_png} not written: {exc}")
    if not srde_only:
        files["backbone_pfm"] = write_disparity(out / BACKBONE_PFM, result.backbone_disparity)
        files["srde_pfm"] = write_disparity(out / SRDE_PFM, result.srde_disparity)
    files["source_png"] = write_mask(out / SOURCE_PNG, result.source)
    if rig is not None:
        depth = rig.disparity_to_depth(result.disparity).astype(np.float32)
        files["depth_pfm"] = write_pfm(out / DEPTH_PFM, np.where(np.isnan(depth), np.inf, depth))
        files["points_ply"] = write_ply(out / POINTS_PLY,
                                        *disparity_to_points(result.disparity, rig, image))
        files["color_png"] = write_image(out / COLOR_PNG, colorize_disparity(result.disparity))

    scores = None
    if gt_disparity is not None:
        if region is None and result.objects:
            region = result.source > 0
        scores = score_fusion(result, gt_disparity, region)
    maps = ({"SRDE": result.disparity} if srde_only else
            {"backbone": result.backbone_disparity, "SRDE": result.srde_disparity,
             "fused": result.disparity})
    fig = comparison_figure(image, maps, gt_disparity=gt_disparity, source=result.source,
                            region=region, title=title)
    files["figure_png"] = save_figure(fig, out / FIGURE_PNG)

    report = {"fusion": result.report(), "scores": scores, "notes": notes,
              "files": {k: p.name for k, p in files.items()} | {"report_json": REPORT_JSON}}
    if extra:
        report.update(extra)
    files["report_json"] = out / REPORT_JSON
    written = {p.name for p in files.values()}
    stale = [name for name in OUTPUT_FILES if name not in written and (out / name).is_file()]
    for name in stale:
        (out / name).unlink()
    if stale:
        notes.append(f"removed {', '.join(stale)} left by an earlier run")
        report["notes"] = notes
    # The report is the folder's manifest: written last, it lists what this run wrote.
    write_atomic(files["report_json"], json.dumps(json_safe(report), indent=2, allow_nan=False)
                 + "\n")
    return SceneRun(result, scores, files, tuple(notes))


def run_demo(out_dir: str | os.PathLike = "demo_out", *, seed: int = DEMO_SEED,
             n_objects: int = DEMO_OBJECTS, scale: float = 1.0, backbone: Backbone,
             rig: CameraRig | None = None) -> DemoResult:
    """Run the embedded default: render a scene, run the backbone, fuse, write.

    Renders a textured room with glossy flat objects for the paper's 3x3 array
    (640x480, ``scale`` resizes it), saves it as a scene folder (``out_dir/scene``),
    runs the backbone on the stereo pair, finds the objects with
    the built-in :class:`~srde_fusion.masks.HighlightSegmenter`, fuses, and writes the
    outputs of :func:`write_fusion_outputs` with the ground truth.

    Parameters
    ----------
    out_dir : path
    seed : int
        Scene seed.
    n_objects : int
        Glossy objects in the scene.
    scale : float
        Image scale relative to 640x480 (e.g. 0.5 for a quick run).
    backbone : callable
        ``backbone(left, right) -> (H, W)`` disparity in pixels; the command passes the
        bundled stand-in (``srde_fusion.adapters.load_backbone("default")``).
    rig : CameraRig, optional
        The camera array; the paper's by default.

    Returns
    -------
    DemoResult
    """
    if not (isinstance(scale, (int, float)) and 0.1 <= scale <= 4.0):
        raise SRDEError(f"scale: expected a factor in [0.1, 4], got {scale!r}")
    rig = (rig or default_rig())
    if scale != 1.0:
        rig = rig.scaled(scale)
    _log.info("rendering the demo scene (%d cameras, %dx%d)", rig.n_cameras, *rig.image_size)
    scene = random_scene(seed, rig, n_objects=n_objects, background="textured")
    rig = rig.with_light(scene.light.position_m)
    rendering = render(scene, rig, noise_seed=seed)
    out = Path(out_dir)
    scene_dir = write_scene(out / "scene", rendering.views, rig, mask=rendering.instance_mask,
                            gt_disparity=rendering.disparity_px,
                            metadata={"seed": seed, "scene": scene_to_dict(scene)})

    _log.info("rendered the demo scene into %s; running the backbone and fusing", scene_dir)
    model = HybridStereo(backbone, rig, masker=HighlightSegmenter())
    result = model(rendering.views)
    diagnostics = model.masker.last_diagnostics
    run = write_fusion_outputs(
        out, result, rendering.views[rig.reference], gt_disparity=rendering.disparity_px,
        region=rendering.instance_mask > 0, title=f"demo scene (seed {seed})", rig=rig,
        extra={"scene_dir": scene_dir.name, "masks": _AUTO_MASKS,
               "segmenter": None if diagnostics is None else list(diagnostics.reasons)})
    return DemoResult(run.fusion, run.scores, run.files, run.notes, _AUTO_MASKS, scene_dir)


def fuse_scene(scene_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
               backbone: Backbone | None = None, disparity: Any = None,
               disparity_scale: float = 1.0, mask: Any = None, auto_mask: bool = False,
               light: Any = None, max_faces: int = 1) -> SceneRun:
    """Fuse a backbone's disparity with SRDE for one scene folder and write the outputs.

    Parameters
    ----------
    scene_dir : path
        A scene folder (``rig.json`` with the light, one image per camera, optional
        ``mask.png`` and ground truth).
    out_dir : path
    backbone : callable, optional
        ``backbone(left, right) -> (H, W)`` disparity in pixels (see
        :mod:`srde_fusion.adapters` to wrap a model file or a torch module).
    disparity : path or numpy.ndarray, optional
        Instead of a backbone: the disparity map a pipeline already produced for the
        reference view (PFM, KITTI 16-bit PNG or ``.npy``, see
        :func:`~srde_fusion.io.read_disparity`; or an array). Exactly one of
        ``backbone`` and ``disparity``.
    disparity_scale : float
        Factor from the map's values to pixels of the stereo pair (e.g. 0.5 for a map
        stored at twice the resolution's disparity).
    mask : path or array, optional
        Object masks; the scene's ``mask.png`` if present, else the built-in segmenter.
    auto_mask : bool
        Use the built-in segmenter even if the scene has a mask.
    light : array_like (3,), optional
        Light position in metres, overriding the rig's.
    max_faces : int
        Most flat faces an object may have (1-3); see :class:`~srde_fusion.srde.SRDE`.

    Returns
    -------
    SceneRun
    """
    if (backbone is None) == (disparity is None):
        raise SRDEError("backbone, disparity: expected exactly one (a model to run, or the "
                        f"disparity map it already made), got "
                        f"{'both' if backbone is not None else 'neither'}")
    if (isinstance(disparity_scale, bool) or not isinstance(disparity_scale, (int, float))
            or not (math.isfinite(disparity_scale) and disparity_scale > 0)):
        raise SRDEError(f"disparity_scale: expected a positive number, got {disparity_scale!r}")
    scene = read_scene(scene_dir)
    choice = resolve_masker("auto" if auto_mask and mask is None else mask,
                            scene_labels=scene.mask_labels, where=str(scene.path))
    masker, source = choice.masker, choice.description
    _log.info("%s: masks %s; %s", scene.name, source,
              "running the backbone" if backbone is not None else "using the given disparity")
    if backbone is not None:
        result = HybridStereo(backbone, scene.rig, light, masker,
                              max_faces=max_faces)(scene.views)
    else:
        given = disparity if isinstance(disparity, np.ndarray) else read_disparity(disparity)
        result = postprocess(np.asarray(given, dtype=np.float32) * np.float32(disparity_scale),
                             scene.views, scene.rig, masker, light=light, max_faces=max_faces)
    region = None
    if scene.mask_labels is not None:
        region = scene.mask_labels > 0
    run = write_fusion_outputs(out_dir, result, scene.views[scene.rig.reference],
                                gt_disparity=scene.gt_disparity, region=region,
                                title=scene.name, rig=scene.rig,
                                extra={"scene": str(scene.path),
                                                         "masks": source})
    return dataclasses.replace(run, masks=source)


def srde_scene(scene_dir: str | os.PathLike, out_dir: str | os.PathLike | None = None, *,
               mask: Any = None, auto_mask: bool = False, light: Any = None,
               method: str = "default", max_faces: int = 1) -> SceneRun:
    """Run SRDE alone on one scene folder (no backbone); write its disparity and report.

    Outside the objects there is no disparity (NaN, ``inf`` in the PFM). Parameters as
    :func:`fuse_scene`; ``method`` selects the SRDE variant. Without ``out_dir`` nothing
    is written (the scores against the scene's ground truth are still computed).

    Returns
    -------
    SceneRun
        Its ``fusion`` has an all-invalid backbone, so ``fusion.disparity`` is SRDE's
        map where SRDE succeeded and NaN elsewhere.
    """
    scene = read_scene(scene_dir)
    rig = scene.rig if light is None else scene.rig.with_light(light)
    choice = resolve_masker("auto" if auto_mask and mask is None else mask,
                            scene_labels=scene.mask_labels, where=str(scene.path))
    masker, source = choice.masker, choice.description
    masks = masker(list(scene.views), rig)
    nothing = np.full((rig.height, rig.width), np.nan, np.float32)
    srde = SRDE(rig, method=method, max_faces=max_faces) if masks else None
    result = fuse(nothing, scene.views, rig, masks, srde, border_check=None)
    region = scene.mask_labels > 0 if scene.mask_labels is not None else None
    if out_dir is None:
        scores = None
        if scene.gt_disparity is not None:
            scores = score_fusion(result, scene.gt_disparity,
                                  region if region is not None else result.source > 0)
        return SceneRun(result, scores, {}, masks=source)
    run = write_fusion_outputs(out_dir, result, scene.views[rig.reference],
                                gt_disparity=scene.gt_disparity, region=region,
                                title=f"{scene.name}: SRDE alone", srde_only=True, rig=rig,
                                extra={"scene": str(scene.path), "masks": source})
    return dataclasses.replace(run, masks=source)


@dataclass(frozen=True)
class DatasetRun:
    """What :func:`fuse_dataset` produced: one :class:`SceneRun` per scene, and failures.

    Attributes
    ----------
    runs : dict of str -> SceneRun
        By scene name, in dataset order.
    failures : dict of str -> str
        Scene name -> why it could not be fused.
    """

    runs: dict
    failures: dict

    def summary(self) -> str:
        """One line: scenes fused, objects, how many used SRDE, failures."""
        objects = [o for r in self.runs.values() for o in r.fusion.objects]
        used = sum(o.used_srde for o in objects)
        text = (f"{len(self.runs)} scene(s) fused, {len(objects)} object(s): SRDE used on "
                f"{used}, backbone kept on {len(objects) - used}")
        return text + (f"; {len(self.failures)} scene(s) failed" if self.failures else "")


def fuse_dataset(dataset_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
                 backbone: Backbone, mask: Any = None, auto_mask: bool = False,
                 light: Any = None, progress: bool = True, strict: bool = False,
                 max_faces: int = 1) -> DatasetRun:
    """Fuse every scene folder of a dataset with one backbone, each into ``out_dir/<scene>``.

    Parameters
    ----------
    dataset_dir : path
        A folder of scene folders (see :func:`~srde_fusion.io.list_scenes`).
    out_dir : path
    backbone : callable
        Loaded once, run on every scene.
    mask, auto_mask, light, max_faces
        As :func:`fuse_scene`, for every scene.
    progress : bool
        Show a progress bar on stderr.
    strict : bool
        Stop at the first scene that cannot be fused; by default it is recorded in
        ``failures`` and the others are still fused.

    Returns
    -------
    DatasetRun
    """
    folders = list_scenes(dataset_dir)
    runs, failures = {}, {}
    for folder in tqdm(folders, desc="fusing", unit="scene", disable=not progress):
        try:
            runs[folder.name] = fuse_scene(folder, Path(out_dir) / folder.name,
                                           backbone=backbone, mask=mask, auto_mask=auto_mask,
                                           light=light, max_faces=max_faces)
        except SRDEError as exc:
            if strict:
                raise
            failures[folder.name] = f"{type(exc).__name__}: {exc}"
    return DatasetRun(runs, failures)
