"""Wrap your own stereo network and make it reliable on flat glossy objects.

``MyStereoNet`` stands in for your model: a torch module with its own conventions. Like
RAFT-Stereo it returns *negative* horizontal flow, it needs sizes divisible by 8, and it
answers at half resolution, in half-resolution pixels.
A :class:`~srde_fusion.adapters.StereoSpec` declares those conventions once;
:class:`~srde_fusion.adapters.TorchStereo` undoes them and hands back positive
disparity at input resolution. :class:`~srde_fusion.fusion.fuse.HybridStereo` then runs the
network, the mask stage, SRDE and the fusion in one call.

Usage: ``python examples/wrap_your_model.py``
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from srde_fusion.adapters import StereoSpec, TorchStereo

from srde_fusion.evaluation import evaluate
from srde_fusion.fusion import HybridStereo
from srde_fusion.synthetic import default_rig, random_scene, render


class MyStereoNet(torch.nn.Module):
    """Sum-of-absolute-differences cost volume, winner takes all (no learned weights).

    Takes RGB in 0..255, ``(B, 3, H, W)`` with H and W multiples of 8; returns
    ``(B, 1, H/2, W/2)`` flow in half-resolution pixels, negative for a point that moves
    left in the right view.
    """

    def __init__(self, max_disparity_px: int = 64, window_px: int = 9) -> None:
        super().__init__()
        self.max_disparity_px = max_disparity_px
        self.window_px = window_px

    @staticmethod
    def features(image: torch.Tensor) -> torch.Tensor:
        """Colour in [0, 1] plus the horizontal gradient, which survives brightness changes."""
        x = image / 255.0
        gradient = F.pad((x[..., 1:] - x[..., :-1]).mean(1, keepdim=True), (0, 1))
        return torch.cat([x, 4.0 * gradient], dim=1)  # (B, 3, H, W) -> (B, 4, H, W)

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
        if left.shape[-2] % 8 or left.shape[-1] % 8:
            raise ValueError(f"expected H and W divisible by 8, got {tuple(left.shape[-2:])}")
        # Matching at half resolution: (B, 4, H, W) -> (B, 4, H/2, W/2).
        left = F.avg_pool2d(self.features(left), 2)
        right = F.avg_pool2d(self.features(right), 2)
        costs = []
        for d in range(self.max_disparity_px):
            shifted = F.pad(right, (d, 0))[..., : right.shape[-1]]  # right image moved by d
            sad = (left - shifted).abs().sum(dim=1, keepdim=True)
            costs.append(F.avg_pool2d(sad, self.window_px, 1, self.window_px // 2))
        cost = torch.cat(costs, dim=1)  # (B, D, H, W)
        return -cost.argmin(dim=1, keepdim=True).to(left.dtype)


# The conventions of MyStereoNet, declared once (print(SPEC.summary()) shows them). The
# half-resolution output is recognised from its shape: upsampled and multiplied by 2.
SPEC = StereoSpec(name="my-stereo-net", value_scale=255.0, pad_multiple=8, output_sign=-1.0)


def main() -> None:
    rig = default_rig()
    scene = random_scene(4, rig, n_objects=1, background="textured")
    rig = rig.with_light(scene.light.position_m)
    capture = render(scene, rig, noise_seed=4)

    backbone = TorchStereo(MyStereoNet(), SPEC)
    model = HybridStereo(backbone, rig)  # the built-in highlight segmenter finds the objects
    result = model(capture.views)

    for obj in result.objects:
        print(f"object {obj.index}: {obj.status} - {obj.reason}")
    gt, objects = capture.disparity_px, capture.instance_mask > 0
    for name, d in (("MyStereoNet", result.backbone_disparity), ("hybrid", result.disparity)):
        print(f"{name:>12}: EPE {evaluate(d, gt)['epe']:.3f} px (full scene), "
              f"{evaluate(d, gt, objects)['epe']:.3f} px (objects)")
    np.testing.assert_array_equal(result.disparity[result.source == 0],
                                  result.backbone_disparity[result.source == 0])


if __name__ == "__main__":
    main()
