"""SRDE on renders whose physics the refinement does not model (exact Fresnel, an area
light integrated over its disc, height-correlated masking, diffuse transmittance,
photon noise, pixel-area integration): it must stay accurate, not only on its own model."""

from dataclasses import replace

import numpy as np
import pytest

from srde_fusion.geometry import plane_disparity
from srde_fusion.srde import SRDE
from srde_fusion.synthetic import (
    Physics,
    RandomSceneConfig,
    default_rig,
    random_scene,
    render,
)


def _acrylic(scene):
    objects = tuple(replace(o, material=replace(o.material, ior=1.49)) for o in scene.objects)
    return replace(scene, objects=objects)


@pytest.mark.parametrize(("seed", "roughness", "radius_m"),
                         [(5001, (0.01, 0.02), 0.0), (5010, (0.02, 0.04), 0.01),
                          (5030, (0.04, 0.08), 0.015)])
def test_srde_is_accurate_on_faithful_renders(seed, roughness, radius_m):
    rig = default_rig()
    config = RandomSceneConfig(roughness=roughness, light_radius_m=radius_m,
                               clip_ratio=(2.0, 6.0))
    scene = _acrylic(random_scene(seed, rig, config=config))
    out = render(scene, rig, physics=Physics.faithful(), supersample=2)
    lit = rig.with_light(scene.light.position_m)
    mask = out.object_masks[0]
    result = SRDE(lit).estimate(out.views, mask)
    assert result.ok, result.reason
    geometric = SRDE(lit, refine=False).estimate(out.views, mask)
    error = np.abs(plane_disparity(result.plane, lit)[mask] - out.disparity_px[mask])
    before = np.abs(plane_disparity(geometric.plane, lit)[mask] - out.disparity_px[mask])
    assert float(error.mean()) < 0.02
    assert float(error.mean()) <= float(before.mean())


def test_a_rough_lobe_whose_free_exponent_runs_to_its_bound_is_still_refined():
    # A rough (alpha 0.066), clipped highlight seen by a stereo pair: read in block means,
    # the free foreshortening exponent runs to its bound (-4) in every start, and the
    # geometric plane, 0.41 px off, used to stand. Held at the microfacet value the fit
    # settles. (The pair's default reads every pixel, where this scene's exponent stays
    # inside its range: both are checked.)
    from srde_fusion.geometry import CameraRig

    rig = CameraRig.stereo(0.085, fx=600.0, image_size=(640, 480))
    config = RandomSceneConfig(roughness=(0.04, 0.08), light_radius_m=0.0,
                               clip_ratio=(2.0, 6.0))
    scene = _acrylic(random_scene(5085, rig, config=config))
    out = render(scene, rig, physics=Physics.faithful(), supersample=2)
    lit = rig.with_light(scene.light.position_m)
    mask = out.object_masks[0]
    geometric = SRDE(lit, refine=False).estimate(out.views, mask)
    before = np.abs(plane_disparity(geometric.plane, lit)[mask] - out.disparity_px[mask])
    assert float(before.mean()) > 0.3
    by_pixel = SRDE(lit).estimate(out.views, mask)
    by_block = SRDE(lit, refine_pixels=False).estimate(out.views, mask)
    assert by_block.refinement.n_samples < by_pixel.refinement.n_samples
    assert by_block.ok and by_block.refinement.ok, by_block.notes
    assert by_block.refinement.params.foreshortening == 0.0
    for result, bound_px in ((by_block, 0.01), (by_pixel, 0.02)):  # (pixels: 0.0104)
        assert result.ok and result.refinement.ok, result.notes
        error = np.abs(plane_disparity(result.plane, lit)[mask] - out.disparity_px[mask])
        assert float(error.mean()) < bound_px
