"""SRDE with its pixel work in torch, batched over the views (CPU or GPU)."""

from __future__ import annotations

from .estimator import SRDE

__all__ = ["BatchedSRDE"]


class BatchedSRDE(SRDE):
    """:class:`~srde_fusion.srde.SRDE` on the torch detector backend.

    Same options, same :meth:`~srde_fusion.srde.SRDE.estimate` contract and the same
    :class:`~srde_fusion.srde.SRDEResult`; the views may also be torch tensors already on
    the device. Equivalent to ``SRDE(rig, light, backend="torch", device=device, ...)``.

    Parameters
    ----------
    rig : CameraRig
    light : array_like, (3,), optional
    device : str or torch.device
        Where the pixel work runs: ``"cpu"``, ``"cuda"``, ``"cuda:1"``, ...
    **options
        Every keyword option of :class:`~srde_fusion.srde.SRDE` (``method``, ``detector``,
        ``blob_center``, ``refine``, ...). With ``blob_center="lobe"`` the lobe fit itself
        runs on the host, on the chosen blob's crop.

    Raises
    ------
    SRDEError
        As :class:`~srde_fusion.srde.SRDE`, and for a device that is not available.

    Examples
    --------
    >>> import numpy as np
    >>> from srde_fusion.geometry import CameraRig
    >>> rig = CameraRig.stereo(0.1, fx=400.0, image_size=(96, 64))
    >>> srde = BatchedSRDE(rig, light=[0.05, -0.3, 0.2], device="cpu")
    >>> result = srde.estimate([np.zeros((64, 96), np.uint8)] * 2, np.ones((64, 96), bool))
    >>> result.status, result.reason.split(":")[0]
    ('no_highlight', 'view 0 (left, reference)')
    """

    def __init__(self, rig, light=None, *, device="cpu", **options) -> None:
        super().__init__(rig, light, backend="torch", device=device, **options)
        self.device = self.backend.device
