"""Evaluate backbone, SRDE and the hybrid on a small rendered dataset with ground truth.

Renders a few scenes (textured rooms with glossy flat objects, 3x3 array, 640x480) as
scene folders, then scores the bundled stand-in stereo network alone, SRDE alone and the
fused map, over the full scene and over the objects. The objects are found by the
built-in highlight segmenter (``masks="user"`` would take each scene's ``mask.png``);
the scores over the objects use the true masks either way. The same from the shell:

    srde-fusion render DATASET --scenes 3 --objects 2 --background textured
    srde-fusion eval DATASET --backbone default --masks auto --out results

Usage: ``python examples/evaluate.py [DATASET_DIR]`` (a temporary folder by default).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from srde_fusion.adapters import load_backbone

from srde_fusion.evaluation import evaluate_dataset
from srde_fusion.synthetic import render_dataset

N_SCENES = 3


def main(dataset_dir: Path) -> None:
    render_dataset(dataset_dir, n_scenes=N_SCENES, seed=2, background="textured", n_objects=2,
                   progress=False)
    backbone = load_backbone("default")
    evaluation = evaluate_dataset(dataset_dir, backbone, masks="auto", progress=False)
    print(evaluation.to_markdown())
    for scene in evaluation.scenes:
        print(f"{scene.name}: " + "; ".join(f"object {o['index']} {o['status']}"
                                            for o in scene.report["objects"]))


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            main(Path(tmp) / "dataset")
