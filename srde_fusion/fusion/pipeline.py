"""Fusion around a stereo pipeline: fix a disparity map it made, or wrap its model.

:func:`postprocess` takes a disparity map an existing pipeline already produced;
:class:`HybridStereo` wraps a backbone callable into a model that returns the fused map.
Both find the objects with a mask stage (:func:`~srde_fusion.masks.resolve_masker`) and
run SRDE and :func:`~srde_fusion.fusion.fuse` on them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from .._checks import check_disparity, check_views
from ..errors import BackboneError, LightError, RigError
from ..geometry import CameraRig
from ..masks import resolve_masker
from ..srde import SRDE
from .checks import DEFAULT_BORDER_CHECK, BorderCheck
from .fuse import as_mask_list, fuse
from .lamps import LampTally
from .report import FusionResult
from .stream import FrameTiming, FusionStream

__all__ = [
    "postprocess",
    "HybridStereo",
]

Backbone = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _rig_with_light(rig: CameraRig, light: Any) -> CameraRig:
    if not isinstance(rig, CameraRig):
        raise RigError(f"rig: expected a CameraRig, got {type(rig).__name__}")
    if light is not None:
        return rig.with_light(light)
    if rig.light_position_m is None:
        raise LightError("light: expected a light position (x, y, z) in metres, given here or in "
                         "the rig, got None")
    return rig


def postprocess(disparity: np.ndarray, views: Sequence[np.ndarray], rig: CameraRig,
                masks: Any = None, *, light: Any = None, srde_method: str = "default",
                border_check: BorderCheck | None = DEFAULT_BORDER_CHECK,
                max_faces: int = 1) -> FusionResult:
    """Fix a disparity map an existing pipeline produced, on flat glossy objects.

    Parameters
    ----------
    disparity : numpy.ndarray, (H, W), float, pixels
        The pipeline's disparity for the reference view of ``rig`` (stereo-pair
        convention, ``d = fx * B / z``).
    views : sequence of numpy.ndarray, (H, W, 3) uint8
        One image per rig camera.
    rig : CameraRig
    masks : None, path, array, list of masks or masker
        Where the objects are: None runs the built-in
        :class:`~srde_fusion.masks.stages.HighlightSegmenter`; a path or array is read as user
        masks (:class:`~srde_fusion.masks.stages.UserMasks`); a callable
        ``masker(views, rig) -> list of masks`` is called.
    light : array_like (3,), optional
        Light position in the array frame, metres; the rig's by default.
    srde_method : str
        SRDE variant, see :class:`~srde_fusion.srde.estimator.SRDE`.
    border_check : BorderCheck or None
        See :func:`fuse`.
    max_faces : int
        Most flat faces an object may have (1-3), see
        :class:`~srde_fusion.srde.estimator.SRDE`; a faceted object's fused map carries
        each face's plane on its part.

    Returns
    -------
    FusionResult
    """
    rig = _rig_with_light(rig, light)
    views = check_views(views, rig.n_cameras, rig.image_size)
    w, h = rig.image_size
    backbone = check_disparity(disparity, (h, w), "disparity")
    masker = resolve_masker(masks).masker
    return fuse(backbone, views, rig, masker(views, rig),
                SRDE(rig, method=srde_method, max_faces=max_faces), border_check=border_check)


class HybridStereo:
    """A stereo model made reliable on flat glossy objects: backbone + SRDE + fusion.

    Parameters
    ----------
    backbone : callable
        ``backbone(left, right) -> (H, W) float32`` disparity in pixels (see
        ``srde_fusion.adapters.load_backbone`` to build one from an ONNX file or a
        torch module). It receives the views of the rig's stereo pair.
    rig : CameraRig
    light : array_like (3,), optional
        Light position in the array frame, metres; the rig's by default.
    masker : callable, optional
        ``masker(views, rig) -> list of (H, W) bool``; the built-in
        :class:`~srde_fusion.masks.stages.HighlightSegmenter` by default. Paths and arrays are
        taken as fixed user masks.
    srde_method : str
        SRDE variant, see :class:`~srde_fusion.srde.estimator.SRDE`.
    border_check : BorderCheck or None
        See :func:`fuse`.
    max_faces : int
        Most flat faces an object may have (1-3), see
        :class:`~srde_fusion.srde.estimator.SRDE`; a faceted object's fused map carries
        each face's plane on its part.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(32, 24), light_position_m=(0, -0.3, 0))
    >>> model = HybridStereo(lambda left, right: np.full((24, 32), 5.0, np.float32), rig,
    ...                      masker=lambda views, rig: [])
    >>> views = [np.zeros((24, 32, 3), np.uint8)] * 2
    >>> result = model(views)
    >>> float(result.disparity[0, 0]), result.objects
    (5.0, ())
    """

    def __init__(self, backbone: Backbone, rig: CameraRig, light: Any = None,
                 masker: Any = None, *, srde_method: str = "default",
                 border_check: BorderCheck | None = DEFAULT_BORDER_CHECK,
                 max_faces: int = 1) -> None:
        if not callable(backbone):
            raise BackboneError(f"backbone: expected a callable backbone(left, right), got "
                            f"{type(backbone).__name__}")
        self.rig = _rig_with_light(rig, light)
        self.backbone = backbone
        self.masker = resolve_masker(masker).masker
        self.srde_method = srde_method
        self.max_faces = max_faces
        self.border_check = border_check
        self._srde = None

    @property
    def srde(self) -> SRDE:
        """The SRDE estimator for this rig (built on first use)."""
        if self._srde is None:
            self._srde = SRDE(self.rig, method=self.srde_method, max_faces=self.max_faces)
        return self._srde

    def __call__(self, views: Sequence[np.ndarray]) -> FusionResult:
        """Run backbone, mask stage, SRDE and fusion on one set of views.

        Parameters
        ----------
        views : sequence of numpy.ndarray, (H, W, 3) uint8
            One image per rig camera.

        Returns
        -------
        FusionResult
        """
        return self._run(views)[0]

    def stream(self, frames: Iterable[Sequence[np.ndarray]]) -> FusionStream:
        """Fuse a sequence of frames from this rig, one result per frame, with their rate.

        What depends only on the rig is done once for the whole stream: the rig and
        light are checked, SRDE's search geometry and highlight detector are built
        before the first frame, and the mask stage is kept. Frames are read from
        ``frames`` one at a time, as results are asked for, so a camera generator or a
        folder reader can feed it without holding the sequence in memory.

        Parameters
        ----------
        frames : iterable of sequences of numpy.ndarray, (H, W, 3) uint8
            Each item is one frame: one image per rig camera, in the rig's order.

        Returns
        -------
        FusionStream
            An iterator of :class:`FusionResult`, one per frame; its ``stats``
            (:class:`~srde_fusion.fusion.stream.StreamStats`) give the frames per second
            and the time per stage, its ``last_timing`` the last frame's stages, its
            ``lamps`` (:class:`~srde_fusion.fusion.lamps.LampTally`) which of the rig's
            lamps the solved objects see (``stream.lamps.warning()`` names one that seems
            switched off).

        Raises
        ------
        ImageError
            When a frame is reached whose views do not fit the rig.

        Examples
        --------
        >>> import numpy as np
        >>> from srde_fusion import CameraRig
        >>> rig = CameraRig.stereo(0.1, fx=100.0, image_size=(32, 24),
        ...                        light_position_m=(0, -0.3, 0))
        >>> model = HybridStereo(lambda l, r: np.full((24, 32), 5.0, np.float32), rig,
        ...                      masker=lambda views, rig: [])
        >>> frames = ([np.zeros((24, 32, 3), np.uint8)] * 2 for _ in range(3))
        >>> stream = model.stream(frames)
        >>> [float(result.disparity[0, 0]) for result in stream], stream.stats.frames
        ([5.0, 5.0, 5.0], 3)
        """
        _ = self.srde  # built now, so the first frame costs what every other one does
        return FusionStream(self._run, frames,
                            LampTally.for_rig(self.rig, self.srde.min_views))

    def _run(self, views: Sequence[np.ndarray]) -> tuple[FusionResult, FrameTiming]:
        """Fuse one frame; return the result and the time of each stage."""
        rig = self.rig
        t0 = time.perf_counter()
        views = check_views(views, rig.n_cameras, rig.image_size)
        left, right = (views[i] for i in rig.stereo_pair)
        disparity = self.backbone(left, right)
        t1 = time.perf_counter()
        # Checked here so that a masker returning None or a generator is a MaskError.
        masks = as_mask_list(self.masker(views, rig), (rig.height, rig.width))
        t2 = time.perf_counter()
        srde = self.srde if masks else None
        result = fuse(disparity, views, rig, masks, srde, border_check=self.border_check)
        return result, FrameTiming(t1 - t0, t2 - t1, time.perf_counter() - t2)
