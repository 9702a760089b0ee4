"""Small synthetic scenes shared by the robustness tests (imported, not collected).

A plane, a light and a rectified rig fix the virtual light exactly; each view gets a
Gaussian highlight at the virtual light's projection on a flat background, so every
test knows the true plane, the true centres and the true disparity.
"""

from __future__ import annotations

import numpy as np

from srde_fusion.geometry import CameraRig, Plane, plane_disparity
from srde_fusion.imaging import linear_to_srgb, srgb_to_linear

W, H = 200, 150
FX_PX = 200.0
BASELINE_M = 0.085
#: A plane about 0.8 m in front of the array, tilted a little, and a light beside it.
PLANE = Plane.from_point_normal([0.02, 0.01, 0.8], [0.15, -0.1, -1.0])
LIGHT_M = np.array([0.2, -0.3, 0.05])
#: The object's mask in the reference view.
MASK_BOX = (40, 30, 170, 130)  # u0, v0, u1, v1


def grid_rig(light_m=LIGHT_M) -> CameraRig:
    """The paper's 3x3 layout at a small image size, with the light."""
    return CameraRig.grid(3, 3, baseline_m=BASELINE_M, fx=FX_PX, image_size=(W, H),
                          light_position_m=None if light_m is None else tuple(light_m))


def box_mask(box=MASK_BOX) -> np.ndarray:
    """``(H, W)`` bool mask of a box ``(u0, v0, u1, v1)``."""
    u0, v0, u1, v1 = box
    mask = np.zeros((H, W), dtype=bool)
    mask[v0:v1, u0:u1] = True
    return mask


def true_centers(rig: CameraRig, plane: Plane = PLANE, light_m=LIGHT_M) -> np.ndarray:
    """Projection of the virtual light into every view, ``(N, 2)`` px."""
    virtual = plane.mirror(np.asarray(light_m, dtype=np.float64))
    return np.stack([rig.project(virtual, j) for j in range(rig.n_cameras)])


def true_disparity(rig: CameraRig, plane: Plane = PLANE) -> np.ndarray:
    """The plane's stereo-pair disparity at every reference pixel, ``(H, W)`` px."""
    return plane_disparity(plane, rig)


def highlight_views(centers, *, sigma_px=3.0, peak=2.0, background=0.06, rgb=True,
                    extra=None) -> list[np.ndarray]:
    """8-bit sRGB views with a Gaussian highlight (clipped core) at each centre.

    ``centers`` rows that hold NaN get no highlight. ``extra`` maps a view index to a
    list of ``(u, v, peak, sigma)`` additional blobs (distractors).
    """
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    views = []
    for j, c in enumerate(np.asarray(centers, dtype=np.float64)):
        linear = np.full((H, W), background)
        blobs = [] if not np.all(np.isfinite(c)) else [(c[0], c[1], peak, sigma_px)]
        blobs += list((extra or {}).get(j, []))
        for u, v, amplitude, sigma in blobs:
            linear = linear + amplitude * np.exp(-((uu - u) ** 2 + (vv - v) ** 2)
                                                 / (2 * sigma ** 2))
        grey = np.round(linear_to_srgb(np.clip(linear, 0, 1)) * 255).astype(np.uint8)
        views.append(np.repeat(grey[:, :, None], 3, axis=2) if rgb else grey)
    return views


def add_linear(view: np.ndarray, linear_offset: np.ndarray) -> np.ndarray:
    """Add linear intensity to an 8-bit sRGB view (e.g. a texture or a second blob)."""
    lin = srgb_to_linear(view.astype(np.float32) / 255.0)
    if lin.ndim == 3:
        linear_offset = linear_offset[:, :, None]
    out = linear_to_srgb(np.clip(lin + linear_offset, 0, 1))
    return np.round(out * 255).astype(np.uint8)


def masked_epe(disparity: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    """Mean |disparity - truth| over the mask (NaN predictions are an error of +inf)."""
    err = np.abs(disparity[mask].astype(np.float64) - truth[mask])
    return float(np.mean(np.where(np.isfinite(err), err, np.inf)))


#: What :func:`flat` answers everywhere, pixels.
FLAT_PX = 15.0


def flat(left, right):
    """A backbone that answers 15 px everywhere."""
    return np.full(left.shape[:2], FLAT_PX, np.float32)


def export_constant_model(path, value_px: float, output_name: str = "disp"):
    """Export an ONNX 'stereo network' answering ``value_px`` everywhere (dynamic size).

    The right image enters the graph (times 0) so the model has two real inputs.
    """
    import warnings

    import torch

    class Constant(torch.nn.Module):
        def forward(self, left, right):
            return torch.full_like(left[:, :1], value_px) + 0.0 * right[:, :1]

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy exporter announces its deprecation
        torch.onnx.export(Constant().eval(),
                          (torch.zeros(1, 3, 24, 32), torch.zeros(1, 3, 24, 32)), str(path),
                          input_names=["left", "right"], output_names=[output_name],
                          dynamic_axes={"left": {2: "h", 3: "w"}, "right": {2: "h", 3: "w"},
                                        output_name: {2: "h", 3: "w"}}, dynamo=False)
    return path


def run_cli(capsys, *argv):
    """Run the command in-process: exit code, stdout and stderr."""
    from srde_fusion.cli import main

    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def write_capture_folders(root, rig: CameraRig, view_sets) -> list:
    """Write each capture's views as ``root/capture<c>/<camera>.png``; return the folders."""
    from srde_fusion.io import write_image

    folders = []
    for c, views in enumerate(view_sets):
        folder = root / f"capture{c}"
        folder.mkdir()
        for name, view in zip(rig.camera_names, views, strict=True):
            write_image(folder / f"{name}.png", view)
        folders.append(folder)
    return folders
