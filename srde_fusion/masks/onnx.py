"""A segmentation network exported to ONNX as the mask stage."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from .._checks import check_views
from ..errors import BackboneError, FileFormatError, SRDEError
from ..geometry import CameraRig
from ..imaging import to_float
from .boxed import BoxedMasks
from .user import connected_components

__all__ = [
    "OnnxMasker",
]

# --------------------------------------------------------------------------- ONNX masker
class OnnxMasker:
    """Any segmentation network exported to ONNX, as a masker.

    The network takes ``(B, 3, H, W)`` float32 RGB and returns ``(B, 1, H, W)`` (object
    vs background) or ``(B, K, H, W)``. Inputs are resized to ``input_size`` (or the
    model's fixed size) and outputs back to the image size before thresholding.

    Parameters
    ----------
    path : path
        The ``.onnx`` file.
    threshold : float
        Probability above which a pixel is inside (binary and instance outputs).
    output : {"logits", "probabilities"}
        What the network returns: logits (sigmoid for one channel or
        ``layout="instances"``, softmax for classes) or probabilities already.
    layout : {"classes", "instances"}
        For ``K > 1`` channels: ``"classes"`` — channel 0 is background, each pixel takes
        its most probable class and each class splits into connected components;
        ``"instances"`` — each channel is one object's mask. A single channel is always
        a foreground map split into connected components.
    input_size : (int, int), optional
        ``(width, height)`` the network expects; the model's static input size, or the
        image size, by default.
    input_scale : float
        Factor applied to 0..255 pixel values before ``mean`` and ``std``.
    mean, std : (float, float, float)
        Per-channel normalisation after scaling: ``(x * input_scale - mean) / std``.
    min_area_px : int
        Components smaller than this (at image size) are dropped.
    providers : list of str, optional
        onnxruntime execution providers; CPU by default.
    """

    def __init__(self, path: str | os.PathLike, *, threshold: float = 0.5,
                 output: str = "logits", layout: str = "classes",
                 input_size: tuple[int, int] | None = None, input_scale: float = 1.0 / 255.0,
                 mean: Sequence[float] = (0.0, 0.0, 0.0), std: Sequence[float] = (1.0, 1.0, 1.0),
                 min_area_px: int = 64, providers: Sequence[str] | None = None) -> None:
        if output not in ("logits", "probabilities"):
            raise SRDEError(f"output: expected 'logits' or 'probabilities', got {output!r}")
        if layout not in ("classes", "instances"):
            raise SRDEError(f"layout: expected 'classes' or 'instances', got {layout!r}")
        if not 0.0 < threshold < 1.0:
            raise SRDEError(f"threshold: expected a probability in (0, 1), got {threshold!r}")
        path = Path(path)
        if not path.is_file():
            raise FileFormatError(f"segmentation model: expected an existing .onnx file, got "
                                  f"{str(path)!r}")
        # onnxruntime loads only when an ONNX mask stage is built (a heavy import).
        import onnxruntime as ort

        try:
            self._session = ort.InferenceSession(
                str(path), providers=list(providers or ["CPUExecutionProvider"]))
        except Exception as exc:  # onnxruntime raises its own types for malformed files
            raise FileFormatError(f"{path}: expected a valid ONNX model, got "
                                  f"{type(exc).__name__}: {str(exc).splitlines()[0]}") from None
        inputs = self._session.get_inputs()
        if len(inputs) != 1 or len(inputs[0].shape) != 4:
            raise BackboneError(f"{path}: expected one (B, 3, H, W) input, got "
                                f"{[(i.name, i.shape) for i in inputs]}")
        self._input_name = inputs[0].name
        static = inputs[0].shape[2:]
        if input_size is None and all(isinstance(s, int) and s > 0 for s in static):
            input_size = (static[1], static[0])
        self.path = path
        self.threshold = float(threshold)
        self.output = output
        self.layout = layout
        self.input_size = None if input_size is None else (int(input_size[0]), int(input_size[1]))
        self.input_scale = float(input_scale)
        self.mean = np.asarray(mean, dtype=np.float32).reshape(3, 1, 1)
        self.std = np.asarray(std, dtype=np.float32).reshape(3, 1, 1)
        self.min_area_px = int(min_area_px)

    def __call__(self, views: Sequence[np.ndarray], rig: CameraRig) -> list[np.ndarray]:
        """Masks of the objects the network finds in the reference view.

        Returns
        -------
        list of numpy.ndarray, (H, W), bool
        """
        views = check_views(views, rig.n_cameras, rig.image_size)
        return self.predict(views[rig.reference])

    def predict(self, image: np.ndarray) -> list[np.ndarray]:
        """Masks for one RGB image.

        Parameters
        ----------
        image : numpy.ndarray, (H, W, 3) uint8

        Returns
        -------
        list of numpy.ndarray, (H, W), bool
        """
        h, w = image.shape[:2]
        rgb = to_float(image) * 255.0 if image.dtype != np.uint8 else image.astype(np.float32)
        if rgb.ndim == 2:
            rgb = np.repeat(rgb[:, :, None], 3, axis=2)
        if self.input_size is not None and self.input_size != (w, h):
            shrink = self.input_size[0] < w
            rgb = cv2.resize(rgb, self.input_size,
                             interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        x = (rgb.transpose(2, 0, 1) * self.input_scale - self.mean) / self.std
        x = x[None].astype(np.float32)  # (3, h, w) -> (1, 3, h, w)
        try:
            out = self._session.run(None, {self._input_name: x})[0]
        except Exception as exc:
            raise BackboneError(f"{self.path}: inference failed on a {tuple(x.shape)} input: "
                                f"{str(exc).splitlines()[0]}") from None
        out = np.asarray(out, dtype=np.float32)
        if out.ndim == 3:
            out = out[:, None]  # (B, H, W) -> (B, 1, H, W)
        if out.ndim != 4 or out.shape[0] != 1:
            raise BackboneError(f"{self.path}: expected an output of shape (1, K, H, W), got "
                                f"{out.shape}")
        maps = out[0]
        n_channels = maps.shape[0]
        if n_channels > 1 and self.layout == "classes":
            probs = _softmax(maps) if self.output == "logits" else maps
        else:
            probs = _sigmoid(maps) if self.output == "logits" else maps
        # (K, h', w') -> (K, H, W); probabilities resize smoothly, labels would not.
        if probs.shape[1:] != (h, w):
            probs = np.stack([cv2.resize(p, (w, h), interpolation=cv2.INTER_LINEAR) for p in probs])
        if n_channels == 1:
            return BoxedMasks(connected_components(probs[0] > self.threshold, self.min_area_px),
                              (h, w))
        if self.layout == "instances":
            return [m for m in (p > self.threshold for p in probs)
                    if np.count_nonzero(m) >= self.min_area_px]
        winner = np.argmax(probs, axis=0)
        return BoxedMasks([c for cls in range(1, n_channels)
                           for c in connected_components(winner == cls, self.min_area_px)],
                          (h, w))


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (0.5 * (1.0 + np.tanh(0.5 * x))).astype(np.float32)  # overflow-free logistic


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(axis=0, keepdims=True))
    return (e / e.sum(axis=0, keepdims=True)).astype(np.float32)
