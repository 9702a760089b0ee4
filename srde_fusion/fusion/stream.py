"""Frame sequences from a fixed rig: one fused map per frame, and how fast they come.

A sorting line or a robot cell films one scene after another with the same cameras and
light. :meth:`~srde_fusion.fusion.pipeline.HybridStereo.stream` runs the model on each
frame in turn, reusing what depends only on the rig (the rig and light, checked once;
SRDE's search geometry and highlight detector; the mask stage), and a
:class:`FusionStream` yields the :class:`~srde_fusion.fusion.report.FusionResult` of each
frame while it keeps the time spent per stage (:class:`FrameTiming`) and the frame rate
(:class:`StreamStats`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from ..srde import SRDEResult
from .lamps import LampTally
from .report import FusionResult

__all__ = ["FrameTiming", "StreamStats", "FusionStream"]


@dataclass(frozen=True)
class FrameTiming:
    """Wall-clock time of one frame, by stage, seconds.

    Attributes
    ----------
    backbone_s : float
        The backbone on the stereo pair.
    masks_s : float
        The mask stage.
    fusion_s : float
        SRDE on every object, and the fusion.
    """

    backbone_s: float
    masks_s: float
    fusion_s: float

    @property
    def total_s(self) -> float:
        """All stages of the frame, seconds."""
        return self.backbone_s + self.masks_s + self.fusion_s


@dataclass(frozen=True)
class StreamStats:
    """What a stream has done so far.

    Attributes
    ----------
    frames : int
        Frames fused.
    busy_s : float
        Time spent fusing them (the sum of their :class:`FrameTiming` totals), seconds.
    wall_s : float
        Time from the first frame asked for to the last one returned, seconds: also
        counts reading the frames and whatever the caller did between them.
    backbone_s, masks_s, fusion_s : float
        ``busy_s`` by stage, seconds.
    """

    frames: int = 0
    busy_s: float = 0.0
    wall_s: float = 0.0
    backbone_s: float = 0.0
    masks_s: float = 0.0
    fusion_s: float = 0.0

    @property
    def fps(self) -> float:
        """Frames per second of fusing time (NaN before the first frame)."""
        return self.frames / self.busy_s if self.busy_s > 0 else math.nan

    @property
    def wall_fps(self) -> float:
        """Frames per second of wall-clock time, frame source and caller included."""
        return self.frames / self.wall_s if self.wall_s > 0 else math.nan

    def added(self, timing: FrameTiming, wall_s: float) -> StreamStats:
        """Return the stats with one more frame, fused in ``timing``, at ``wall_s``."""
        return StreamStats(self.frames + 1, self.busy_s + timing.total_s, wall_s,
                           self.backbone_s + timing.backbone_s, self.masks_s + timing.masks_s,
                           self.fusion_s + timing.fusion_s)

    def summary(self) -> str:
        """One line: frames, frames per second, and where the time went."""
        if not self.frames:
            return "0 frames"
        share = {name: value / self.busy_s if self.busy_s > 0 else math.nan
                 for name, value in (("backbone", self.backbone_s), ("masks", self.masks_s),
                                     ("SRDE and fusion", self.fusion_s))}
        parts = ", ".join(f"{name} {value:.0%}" for name, value in share.items())
        return (f"{self.frames} frames, {self.fps:.2f} frames/s fusing ({parts}); "
                f"{self.wall_fps:.2f} frames/s wall-clock")


Run = Callable[[Sequence[np.ndarray]], tuple[FusionResult, FrameTiming]]


class FusionStream(Iterator[FusionResult]):
    """An iterator of fused frames that keeps their timing.

    Made by :meth:`~srde_fusion.fusion.pipeline.HybridStereo.stream`; frames are read
    from the source and fused one at a time, when the next result is asked for.

    Parameters
    ----------
    run : callable
        ``run(views) -> (FusionResult, FrameTiming)`` for one frame.
    frames : iterable of sequences of numpy.ndarray
        Each item is one frame: one image per rig camera.
    lamps : LampTally, optional
        The rig's lamps, empty: the stream counts which ones its solved objects see.

    Attributes
    ----------
    stats : StreamStats
        Frames fused so far and their rate.
    last_timing : FrameTiming or None
        The stages of the last frame fused.
    lamps : LampTally or None
        Per lamp of the rig, the solved objects so far that saw it and those that needed
        it dark (``lamps.warning()`` names a lamp that seems switched off); None when not
        given.
    """

    def __init__(self, run: Run, frames: Iterable[Sequence[np.ndarray]],
                 lamps: LampTally | None = None) -> None:
        self._run = run
        self._frames = iter(frames)
        self._start: float | None = None
        self.stats = StreamStats()
        self.last_timing: FrameTiming | None = None
        self.lamps = lamps

    def __iter__(self) -> FusionStream:
        return self

    def __next__(self) -> FusionResult:
        if self._start is None:
            self._start = time.perf_counter()
        views = next(self._frames)  # StopIteration ends the stream
        result, timing = self._run(views)
        self.last_timing = timing
        self.stats = self.stats.added(timing, time.perf_counter() - self._start)
        if self.lamps is not None:
            self.lamps = self.lamps.added(o.estimate.result for o in result.objects
                                          if isinstance(o.estimate.result, SRDEResult))
        return result
