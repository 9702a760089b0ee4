"""Which of the rig's lamps the frames show: a listed lamp that never lights, across frames.

SRDE takes the rig as the truth: a lamp ``rig.json`` lists is lit. One frame cannot
always tell a lamp switched off from one whose highlight merely falls off the object:
with two lamps listed and one dark, the lit lamp's blobs are the image of either lamp on
its own plane, and such objects are refused as ``ambiguous``; with more lamps, a stale
rig can even make the lit lamps' blobs fit a wrong plane. Over a stream of frames the
objects turn, and the lamps show: a lamp that every solved object's plane puts on the
object, where the images are dark, and that no solved object sees, is switched off or
hidden. :class:`LampTally` counts that evidence frame by frame; it reports, and leaves the
rig to its owner.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np

from ..errors import SRDEError
from ..geometry import CameraRig
from ..srde import SRDEResult
from ..srde.lights import dark_lamps

__all__ = ["LampTally", "MIN_DARK_OBJECTS", "MIN_DARK_REFUSALS"]

#: A lamp is reported as unseen when at least this many solved objects put its
#: highlights on the object where the images are dark, and no solved object sees it.
#: One object can be a lamp hidden from it (another part of the line in the way); two
#: objects of different frames are the stream's evidence.
MIN_DARK_OBJECTS = 2

#: With two lamps listed and one dark, nearly every object is refused as ``ambiguous``
#: (each lamp's reading needs the other dark) and none names the lamp: the stream says a
#: lamp may be off when at least this many objects were refused so, and no fewer than
#: it solved.
MIN_DARK_REFUSALS = 3


@dataclass(frozen=True)
class LampTally:
    """Per lamp of the rig, the solved objects that saw it and those that needed it dark.

    Made empty by :meth:`for_rig`; :meth:`added` counts one frame's SRDE results. Only
    the lamps' evidence in objects SRDE solved with several lights counts
    (``SRDEResult.lights``): a refused object's reading is not established.

    Attributes
    ----------
    names : tuple of str
        One per lamp the rig lists, in its order: the lamp's name, or ``light <index>``.
    min_views : int
        Views in which a lamp's highlights must be missing for an object to need it dark
        (the estimator's ``min_views``).
    frames : int
        Frames counted.
    solved : int
        Objects solved with their lights' assignment.
    seen : tuple of int
        Per lamp, solved objects that assigned its highlight a blob in some view.
    dark : tuple of int
        Per lamp, solved objects whose plane puts its highlights on the object in
        ``min_views`` views or more, where the images are dark, and sees it in none.
    refused_dark : int
        Objects refused as ``ambiguous`` because their best reading needs a lamp dark and
        another lamp's reading explains as much (which lamp is dark is not established).
    """

    names: tuple[str, ...]
    min_views: int = 2
    frames: int = 0
    solved: int = 0
    seen: tuple[int, ...] = ()
    dark: tuple[int, ...] = ()
    refused_dark: int = 0

    def __post_init__(self) -> None:
        # An empty tally may be given the names alone: no lamp seen or needed dark yet.
        zeros = (0,) * len(self.names)
        object.__setattr__(self, "seen", tuple(self.seen) or zeros)
        object.__setattr__(self, "dark", tuple(self.dark) or zeros)
        if len(self.seen) != len(self.names) or len(self.dark) != len(self.names):
            raise SRDEError(f"seen, dark: expected one count per lamp ({len(self.names)}), "
                             f"got {len(self.seen)} and {len(self.dark)}")

    @classmethod
    def for_rig(cls, rig: CameraRig, min_views: int = 2) -> LampTally:
        """Return an empty tally for ``rig``'s lamps."""
        return cls(tuple(light.name or f"light {k}" for k, light in enumerate(rig.lights)),
                   min_views)

    def added(self, results: Iterable[SRDEResult]) -> LampTally:
        """Return the tally with one more frame: its objects' SRDE results."""
        seen, dark = list(self.seen), list(self.dark)
        solved, refused_dark = self.solved, self.refused_dark
        for result in results:
            solution = result.lights
            if solution is None or len(solution.assignments) != len(self.names):
                continue  # one light, a faceted object's faces, or no plane at all
            on_object = np.stack([a.on_object for a in solution.assignments])
            missing = np.stack([a.missing for a in solution.assignments])
            needed_dark = dark_lamps(on_object, missing, self.min_views)
            if result.ok:
                solved += 1
                for k, assignment in enumerate(solution.assignments):
                    # A blob of its own, not a view merely excused (its highlight
                    # predicted inside another lamp's blob or cut by the outline): a
                    # dark lamp is excused wherever a lit one's highlight lies near.
                    seen[k] += assignment.n_views > 0
                for k in needed_dark:
                    dark[k] += 1
            elif result.status == "ambiguous" and needed_dark:
                refused_dark += 1
        return replace(self, frames=self.frames + 1, solved=solved, seen=tuple(seen),
                       dark=tuple(dark), refused_dark=refused_dark)

    @property
    def unseen(self) -> tuple[int, ...]:
        """Lamps no solved object sees and at least :data:`MIN_DARK_OBJECTS` need dark."""
        return tuple(k for k in range(len(self.names))
                     if self.seen[k] == 0 and self.dark[k] >= MIN_DARK_OBJECTS)

    @property
    def doubted(self) -> bool:
        """Whether refusals for a lamp that may be dark say a lamp is off, none named.

        At least :data:`MIN_DARK_REFUSALS` objects refused because a reading of their
        highlights needs a lamp dark, and no fewer than the objects solved.
        """
        return self.refused_dark >= max(MIN_DARK_REFUSALS, self.solved)

    def warning(self) -> str:
        """Name each unseen lamp with its evidence; "" when every lamp is accounted for."""
        lines = []
        for k in self.unseen:
            lines.append(
                f"{self.names[k]}: seen on none of the {self.solved} object(s) solved over "
                f"{self.frames} frame(s), and {self.dark[k]} of them put its highlights on "
                f"the object in {self.min_views} or more views, where the images are dark: "
                "is the lamp switched off or hidden? SRDE takes every lamp the rig lists as "
                "lit; list only the lamps that are lit")
        if self.refused_dark and (lines or self.doubted):
            lines.append(
                f"{self.refused_dark} object(s) over {self.frames} frame(s) were refused as "
                f"ambiguous ({self.solved} solved) because a reading of their highlights "
                "needs one of the listed lamps dark and another lamp's reading explains as "
                "much" + ("" if lines else ": is a lamp switched off or hidden? The images "
                          "do not say which; list only the lamps that are lit"))
        return "\n".join(lines)
