"""Scene-folder workflows: read a scene, run the stages, write the outputs.

May import every core subpackage; never :mod:`srde_fusion.adapters` nor
:mod:`srde_fusion.cli` (the command loads backbones and passes them in).
"""

from __future__ import annotations

from .scene_runs import (
    DEMO_OBJECTS,
    DEMO_SEED,
    DatasetRun,
    DemoResult,
    SceneRun,
    fuse_dataset,
    fuse_scene,
    run_demo,
    scores_table,
    srde_scene,
    write_fusion_outputs,
)

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
