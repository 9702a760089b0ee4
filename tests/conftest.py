"""Shared fixtures: the paper's 3x3 array and a small stereo rig (immutable, so session-wide)."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from srde_fusion.geometry import CameraRig
from srde_fusion.synthetic import default_rig, render_dataset

# The machines running the suite are shared; timing-based failures would only be noise.
settings.register_profile("srde", deadline=None, max_examples=50)
# CI explores the same examples every run, so a red build is reproducible; developers get
# fresh examples each run (HYPOTHESIS_PROFILE=srde-ci reproduces CI locally).
settings.register_profile("srde-ci", deadline=None, max_examples=50, derandomize=True)
settings.load_profile(
    os.environ.get("HYPOTHESIS_PROFILE", "srde-ci" if os.environ.get("CI") else "srde")
)


@pytest.fixture(scope="session")
def rig3x3() -> CameraRig:
    """The paper's array: 3x3 cameras, 85 mm baselines, reference = centre camera 4."""
    return CameraRig.grid(
        3, 3, baseline_m=0.085, fx=600.0, fy=600.0, cx=319.5, cy=239.5, image_size=(640, 480)
    )


@pytest.fixture(scope="session")
def small_stereo_rig() -> CameraRig:
    """A 32x24 px two-camera rig, small enough to write and read many images quickly."""
    return CameraRig.stereo(0.1, fx=40.0, image_size=(32, 24), names=("cam0", "cam1"))


@pytest.fixture(scope="session")
def dataset(tmp_path_factory):
    """Two rendered scenes (320x240, one glossy object each, textured background)."""
    root = tmp_path_factory.mktemp("dataset")
    render_dataset(root, n_scenes=2, seed=5, rig=default_rig().scaled(0.5),
                   background="textured", progress=False)
    return root
