"""The light from the plate highlights' images, not only from their centres.

A highlight's blob centre is not where the plate mirrors the light: on a glossy plate
seen at an angle the lobe is skewed, clipped and foreshortened, and its centroid sits
off the mirror point by a few hundredths of a pixel in a pattern shared by every view
and capture. The ray solve (:mod:`.light`) takes that pattern for a slightly different
light, about a millimetre off at a metre, and SRDE's planes, which mirror the light,
inherit it: on rendered scenes the masked EPE with such a light is 10-30 times the EPE
with the true light (``benchmarks/light_calibration.py``).

The plate is a plane whose pose the markers give, so each capture can be read the way
SRDE reads an object, only backwards. SRDE, told of the ray solve's light, fits the
plate's free region as a flat glossy object (its highlight centres, then the
photometric refinement of the lobe over every view); the refined plane and that light
give the virtual light the images show, ``V = mirror(L, P')``, and mirroring ``V``
across the plate's pose from the markers, ``P``, gives the light this capture shows,
``mirror(V, P)``. The captures' lights are averaged. A light a millimetre off hardly
changes the lobe's shape, so ``V`` does not depend on which light SRDE was told, and
one pass suffices.

Because the same lobe model reads the objects later, what the model gets wrong about a
real lobe is partly the same in both and partly cancels: on rendered scenes SRDE with
this light comes within about twice its EPE with the true light (with five plate poses
rendered faithfully, the same).

Several lights (:func:`photometric_lights`) are read by SRDE's joint fit, one lobe per
light on the plate's one plane: the fitted ``P'`` gives each light the capture shows
``mirror(mirror(L_k, P'), P)``. The two mirrors are one small rigid motion, the same for
every light, so the images correct what the lights' errors share and cannot move the
lights apart (``estimate_lights`` uses it for two lamps only).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..geometry import CameraRig, Plane
from ..srde import SRDE
from .board import Board
from .light import LightEstimate, highlight_rms_px, ray_distances_m
from .plate_highlights import plate_highlight_region
from .plate_pose import PlatePose

__all__ = ["PhotometricLight", "photometric_light", "photometric_lights", "with_photometric"]

#: Largest angle (degrees) and distance at the plate's centre (metres) between the lobe
#: fit's plane and the plate's pose from the markers. The fit's plane is the plate moved
#: by about half the ray solve's light error (0.3-0.6 mm and under 0.01 deg on the default
#: rendered plate, 3.6-4.5 mm and 0.02-0.04 deg on one four times rougher, whose rays put
#: the light 7 mm off): a plane farther off is not the plate, or the pose is not its.
MAX_PLATE_ANGLE_DEG = 0.5
MAX_PLATE_GAP_M = 0.02


@dataclass(frozen=True, eq=False)
class PhotometricLight:
    """The light each capture's highlight images show, and their mean.

    Attributes
    ----------
    position_m : numpy.ndarray, (3,) float64, or None
        Mean of the captures' lights, array frame, metres; None when no capture gave one.
    capture_positions_m : tuple of (numpy.ndarray (3,) or None)
        Per capture, the light its images show; None where it gave none (``reasons``).
    reasons : tuple of str
        Per capture, why it gave no light (``""`` where it did).
    spread_cov_m2 : numpy.ndarray, (3, 3) float64
        Covariance of the mean from the captures' scatter (``cov / m`` over the m captures
        that gave a light; zeros with fewer than two).
    """

    position_m: np.ndarray | None
    capture_positions_m: tuple[np.ndarray | None, ...]
    reasons: tuple[str, ...]
    spread_cov_m2: np.ndarray

    @property
    def n_used(self) -> int:
        """Captures that gave a light."""
        return sum(p is not None for p in self.capture_positions_m)


def photometric_light(light_m: np.ndarray, captures: Sequence[Sequence[np.ndarray]],
                      poses: Sequence[PlatePose], rig: CameraRig, board: Board
                      ) -> PhotometricLight:
    """Read every capture's highlight with SRDE's lobe fit and mirror it back.

    Parameters
    ----------
    light_m : numpy.ndarray, (3,)
        The ray solve's light, array frame, metres (SRDE is told of it).
    captures : sequence of sequence of numpy.ndarray
        Per capture, the validated views in rig order.
    poses : sequence of PlatePose
        Per capture, the plate pose from the markers.
    rig : CameraRig
        The rig; a single light it lists lends its radius to the fit.
    board : Board

    Returns
    -------
    PhotometricLight
    """
    light_m = np.asarray(light_m, dtype=np.float64)
    return photometric_lights(light_m[None], captures, poses, rig, board)[0]


def photometric_lights(lights_m: np.ndarray, captures: Sequence[Sequence[np.ndarray]],
                       poses: Sequence[PlatePose], rig: CameraRig, board: Board,
                       shown: Sequence[Sequence[int]] | None = None
                       ) -> tuple[PhotometricLight, ...]:
    """Read every capture's highlights with SRDE's joint lobe fit and mirror them back.

    With several lights SRDE fits one lobe per light on the one plane of the plate
    (:mod:`~srde_fusion.srde.lights`); the fitted plane ``P'`` gives every light the
    capture shows its image light ``mirror(mirror(L_k, P'), P)``.

    Parameters
    ----------
    lights_m : numpy.ndarray, (K, 3)
        The ray solves' lights, array frame, metres (SRDE is told of them).
    captures : sequence of sequence of numpy.ndarray
        Per capture, the validated views in rig order.
    poses : sequence of PlatePose
        Per capture, the plate pose from the markers.
    rig : CameraRig
        The rig; with one light to find, a single light it lists lends its radius to the
        fit (several are fitted as points: which listed lamp is which is not known here).
    board : Board
    shown : sequence of sequence of int, optional
        Per capture, the lights (indices into ``lights_m``) whose highlights it shows;
        only those are given a light from it. By default every capture shows every light.

    Returns
    -------
    tuple of PhotometricLight
        One per light.
    """
    lights_m = np.asarray(lights_m, dtype=np.float64).reshape(-1, 3)
    if shown is None:
        shown = [range(len(lights_m))] * len(poses)
    if len(lights_m) == 1 and len(rig.lights) == 1:
        # Keep what the user measured of the lamp (its radius).
        lit = rig.with_lights([replace(rig.lights[0],
                                       position_m=tuple(float(v) for v in lights_m[0]))])
    else:
        lit = rig.with_lights(lights_m)
    srde = SRDE(lit)
    found: list[list[np.ndarray | None]] = [[] for _ in lights_m]
    reasons: list[list[str]] = [[] for _ in lights_m]
    for views, pose, lights in zip(captures, poses, shown, strict=True):
        plane, why = _plate_plane(srde, views, pose, rig, board)
        for k, light_m in enumerate(lights_m):
            if k not in lights:
                found[k].append(None)
                reasons[k].append("the capture shows no highlight of this light")
            elif plane is None:
                found[k].append(None)
                reasons[k].append(why)
            else:
                found[k].append(pose.plane.mirror(plane.mirror(light_m)))
                reasons[k].append("")
    return tuple(_mean_light(f, r) for f, r in zip(found, reasons, strict=True))


def _plate_plane(srde: SRDE, views: Sequence[np.ndarray], pose: PlatePose, rig: CameraRig,
                 board: Board) -> tuple[Plane | None, str]:
    """Return the plate's plane the lobe fit finds in one capture, or None and why not."""
    # The plate's free centre (no markers, away from its edge) is the "object".
    region = plate_highlight_region(rig, board, pose, rig.reference)
    if not region.any():  # the markers of other views found a plate this one misses
        return None, (f"the plate's free centre is not in the reference view "
                      f"({rig.camera_names[rig.reference]})")
    result = srde.estimate(views, region)
    refinement = result.refinement
    if not result.ok:
        return None, f"SRDE could not read the plate ({result.status}: {result.reason})"
    if refinement is None or not refinement.ok:
        return None, ("the lobe fit did not confirm the plate's highlight ("
                      + (refinement.reason if refinement is not None else "not run") + ")")
    angle_deg, gap_m = _plane_gap(result.plane, pose)
    if angle_deg > MAX_PLATE_ANGLE_DEG or gap_m > MAX_PLATE_GAP_M:
        return None, (f"the lobe fit's plane is {angle_deg:.2f} deg and "
                      f"{gap_m * 1000:.1f} mm from the plate's pose at its centre "
                      f"(limits {MAX_PLATE_ANGLE_DEG:g} deg, "
                      f"{MAX_PLATE_GAP_M * 1000:g} mm): not the plate")
    return result.plane, ""


def _mean_light(found: list[np.ndarray | None], reasons: list[str]) -> PhotometricLight:
    """Return one light's image lights from the captures, their mean and its spread."""
    used = np.array([p for p in found if p is not None]).reshape(-1, 3)
    spread = np.zeros((3, 3))
    if len(used) >= 2:
        spread = np.cov(used, rowvar=False) / len(used)
    return PhotometricLight(used.mean(axis=0) if len(used) else None, tuple(found),
                            tuple(reasons), spread)


def _plane_gap(plane: Plane, pose: PlatePose) -> tuple[float, float]:
    """Angle (degrees) between a plane and the plate, and the plate centre's distance to it."""
    return plane.angle_to(pose.plane), abs(float(plane.signed_distance(pose.center_m)))


def with_photometric(estimate: LightEstimate, fit: PhotometricLight, rig: CameraRig, *,
                     shared_move: bool = False) -> LightEstimate:
    """Move the estimate to the light the highlights' images show (kept if none did).

    The covariance is the ray solve's (its accuracy floor on the centres and its
    leave-one-capture-out spread) plus the scatter of the captures' image lights about
    their mean; the residuals and ray distances are recomputed at the new light, so they
    show how far the centres' rays pass from it.

    ``shared_move``: the images moved several lights by one plane's correction (see
    :func:`photometric_lights`), which fixes what their errors share but not each light's
    own, and moved some rendered lamps farther from the truth (while SRDE read objects
    better with them). The move from the rays' light is then added to the covariance as
    a bias term ``d d^T``, so that the reported uncertainty spans both lights.
    """
    if fit.position_m is None:
        return replace(estimate, photometric=fit)
    position = fit.position_m
    cov = estimate.position_cov_m2 + fit.spread_cov_m2
    how = (f" + the scatter of {fit.n_used} captures' lights from the highlights' images"
           if fit.n_used >= 2 else "; the light from one capture's highlight images")
    if shared_move:
        move = position - estimate.position_m
        cov = cov + np.outer(move, move)
        how += " + their move from the rays' light (one plate plane moved every light)"
    distances = ray_distances_m(position, estimate.ray_origins_m, estimate.ray_directions)
    return replace(
        estimate, position_m=position, residual_m=float(distances.mean()),
        highlight_residual_px=highlight_rms_px(position, estimate.plate_poses,
                                               list(estimate.highlight_centers_px), rig),
        position_std_m=np.sqrt(np.clip(np.diag(cov), 0.0, None)), ray_distances_m=distances,
        position_cov_m2=cov, geometric_position_m=estimate.position_m, photometric=fit,
        uncertainty=estimate.uncertainty + how)
