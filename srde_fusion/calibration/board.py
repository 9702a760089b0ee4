"""The ArUco calibration plate: its layout, its printable image, and its pose in a rig.

The plate carries square ArUco markers of known size at known places (paper §V-C-1:
one marker in each corner) and leaves its centre free for the specular highlight used
to locate the light (:mod:`srde_fusion.calibration.light`).

Plate frame: origin at the plate centre, x to the right and y down in the printed
image, z = 0 on the plate, metres. It is right-handed, so +z points *into* the plate,
away from a viewer who reads the print; the plate normal that faces the cameras is -z.
A marker's corners are listed like OpenCV reports them: top-left, top-right,
bottom-right, bottom-left of the marker as printed.

The plate pose uses every view of the rectified array at once: all cameras share one
orientation and differ only by their known centres, so one rigid pose of the plate in
the array frame explains the marker corners of all views.
"""

from __future__ import annotations

import math
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .._atomic import write_atomic
from .._checks import (
    check_keys,
    check_number,
)
from .._json import dump_json, load_json_source
from ..errors import BoardError

__all__ = [
    "BOARD_FORMAT",
    "Board",
    "BoardMarker",
    "aruco_dictionary",
    "render_board_image",
    "write_board",
]

BOARD_FORMAT = "srde-board/1"
METRES_PER_INCH = 0.0254


# Corners of a marker must describe a square of the declared size to this tolerance.
_SQUARE_TOL_M = 1e-6

#: Largest plate side and marker coordinate, metres: a board is held in front of the
#: cameras; anything larger is a unit mix-up (millimetres for metres).
MAX_BOARD_EXTENT_M = 10.0


# White quiet zone around each marker in the default layout, as a fraction of its side;
# ArUco needs a light border to find the black marker outline.
_DEFAULT_MARGIN_FRACTION = 0.2


# Markers are drawn on a grid fine enough for about this many pixels per side, at most
# this many times finer than the output.
_FINE_MARKER_PX = 1600
_MAX_BOARD_SUPERSAMPLE = 8
#: Highest print resolution drawn; an A4 plate at this dpi is already 140 megapixels.
MAX_DPI = 4800.0


def _number(value: Any, field_name: str, *, positive: bool = False) -> float:
    return check_number(value, field_name, BoardError, positive=positive)


def _check_keys(data: Any, allowed: set[str], where: str) -> None:
    # Every key of a board.json object is required.
    check_keys(data, allowed, allowed, where, BoardError)


def aruco_dictionary(name: str) -> cv2.aruco.Dictionary:
    """Return the predefined OpenCV ArUco dictionary ``name`` (e.g. ``"DICT_4X4_50"``)."""
    value = (
        getattr(cv2.aruco, name, None)
        if isinstance(name, str) and name.startswith("DICT_")
        else None
    )
    if not isinstance(value, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise BoardError(
            f"dictionary: expected an OpenCV ArUco dictionary name such as "
            f"'DICT_4X4_50' (one of {known}), got {name!r}"
        )
    return cv2.aruco.getPredefinedDictionary(value)


@dataclass(frozen=True)
class BoardMarker:
    """One printed marker: its ArUco id and its corners on the plate.

    Parameters
    ----------
    id : int
        Marker id in the board's dictionary.
    corners_m : tuple of 4 (x, y)
        Top-left, top-right, bottom-right, bottom-left corner of the marker as printed,
        plate frame, metres.
    """

    id: int
    corners_m: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class Board:
    """An ArUco calibration plate.

    Parameters
    ----------
    dictionary : str
        OpenCV predefined dictionary name, e.g. ``"DICT_4X4_50"``.
    marker_size_m : float
        Side of each marker's black square, metres.
    plate_size_m : (float, float)
        ``(width, height)`` of the plate, metres; the plate spans
        ``[-w/2, w/2] x [-h/2, h/2]`` in the plate frame.
    markers : tuple of BoardMarker
        The markers, each a square of side ``marker_size_m`` inside the plate.

    Examples
    --------
    >>> board = Board.corner_layout(marker_size_m=0.05, plate_size_m=(0.297, 0.21))
    >>> board.ids.tolist(), board.marker_corners_m.shape
    ([0, 1, 2, 3], (4, 4, 3))
    >>> Board.from_json(board.to_json()) == board
    True
    """

    dictionary: str
    marker_size_m: float
    plate_size_m: tuple[float, float]
    markers: tuple[BoardMarker, ...]

    def __post_init__(self) -> None:
        aruco = aruco_dictionary(self.dictionary)
        size = _number(self.marker_size_m, "marker_size_m", positive=True)
        object.__setattr__(self, "marker_size_m", size)
        plate = self.plate_size_m
        if not isinstance(plate, (tuple, list, np.ndarray)) or len(plate) != 2:
            raise BoardError(f"plate_size_m: expected [width, height] in metres, got {plate!r}")
        plate = (
            _number(plate[0], "plate_size_m[0]", positive=True),
            _number(plate[1], "plate_size_m[1]", positive=True),
        )
        if max(plate) > MAX_BOARD_EXTENT_M:
            raise BoardError(f"plate_size_m: expected a plate at most {MAX_BOARD_EXTENT_M:g} m "
                             f"wide and high (metres, not millimetres), got {list(plate)}")
        object.__setattr__(self, "plate_size_m", plate)
        markers = tuple(self.markers)
        if not markers:
            raise BoardError("markers: expected at least one marker, got none")
        n_ids = aruco.bytesList.shape[0]
        seen: set[int] = set()
        checked = []
        for k, marker in enumerate(markers):
            where = f"markers[{k}]"
            if not isinstance(marker, BoardMarker):
                raise BoardError(f"{where}: expected a BoardMarker, got {type(marker).__name__}")
            mid = marker.id
            if (
                isinstance(mid, bool)
                or not isinstance(mid, (int, np.integer))
                or not 0 <= mid < n_ids
            ):
                raise BoardError(
                    f"{where}.id: expected an integer in [0, {n_ids - 1}] "
                    f"({self.dictionary}), got {mid!r}"
                )
            if int(mid) in seen:
                raise BoardError(f"{where}.id: expected unique marker ids, got {int(mid)} twice")
            seen.add(int(mid))
            corners = _marker_corners(marker.corners_m, where)
            _check_square(corners, size, where)
            half = np.array(plate) / 2.0
            if np.any(np.abs(corners) > half + _SQUARE_TOL_M):
                raise BoardError(
                    f"{where}.corners: expected the marker inside the plate "
                    f"[-{half[0]:g}, {half[0]:g}] x [-{half[1]:g}, {half[1]:g}] m, "
                    f"got corners {corners.tolist()}"
                )
            checked.append(
                BoardMarker(int(mid), tuple(tuple(float(v) for v in c) for c in corners))
            )
        object.__setattr__(self, "markers", tuple(checked))

    # ------------------------------------------------------------------ constructors
    @classmethod
    def corner_layout(
        cls,
        *,
        dictionary: str = "DICT_4X4_50",
        marker_size_m: float = 0.05,
        plate_size_m: tuple[float, float] = (0.297, 0.21),
        margin_m: float | None = None,
        first_id: int = 0,
    ) -> Board:
        """One marker in each corner of the plate, the centre left free for the highlight.

        The default plate is A4 landscape with 5 cm markers, as on the paper's plate.

        Parameters
        ----------
        dictionary : str
            OpenCV predefined dictionary name.
        marker_size_m : float
            Side of each marker, metres.
        plate_size_m : (float, float)
            ``(width, height)`` of the plate, metres.
        margin_m : float, optional
            White border between each marker and the plate edges, metres;
            ``0.2 * marker_size_m`` by default.
        first_id : int
            Ids are ``first_id .. first_id + 3``: top-left, top-right, bottom-right,
            bottom-left.
        """
        size = _number(marker_size_m, "marker_size_m", positive=True)
        margin = (
            size * _DEFAULT_MARGIN_FRACTION if margin_m is None else _number(margin_m, "margin_m")
        )
        if margin < 0:
            raise BoardError(f"margin_m: expected a non-negative number, got {margin}")
        if not isinstance(plate_size_m, (tuple, list)) or len(plate_size_m) != 2:
            raise BoardError(
                f"plate_size_m: expected (width, height) in metres, got {plate_size_m!r}"
            )
        w = _number(plate_size_m[0], "plate_size_m[0]", positive=True)
        h = _number(plate_size_m[1], "plate_size_m[1]", positive=True)
        # Markers must leave a free band between them in both directions, or there is no
        # room for the highlight in the middle.
        needed = 2 * (size + margin)
        if w <= needed or h <= needed:
            raise BoardError(
                f"plate_size_m: expected a plate larger than {needed:g} m in both "
                f"directions for {size:g} m markers with {margin:g} m margins, "
                f"got {w:g} x {h:g} m"
            )
        x0, x1 = -w / 2 + margin, w / 2 - margin - size
        y0, y1 = -h / 2 + margin, h / 2 - margin - size
        markers = tuple(
            BoardMarker(first_id + k, ((x, y), (x + size, y), (x + size, y + size), (x, y + size)))
            for k, (x, y) in enumerate(((x0, y0), (x1, y0), (x1, y1), (x0, y1)))
        )
        return cls(dictionary, size, (w, h), markers)

    # ------------------------------------------------------------------ properties
    @property
    def ids(self) -> np.ndarray:
        """Marker ids in board order, ``(M,)`` int."""
        return np.array([m.id for m in self.markers], dtype=np.int64)

    @property
    def marker_corners_m(self) -> np.ndarray:
        """Marker corners in the plate frame, ``(M, 4, 3)`` float64, metres (z = 0)."""
        xy = np.array([m.corners_m for m in self.markers], dtype=np.float64)
        return np.concatenate([xy, np.zeros(xy.shape[:2] + (1,))], axis=-1)

    @property
    def outline_m(self) -> np.ndarray:
        """Plate corners (top-left, top-right, bottom-right, bottom-left), ``(4, 3)``, metres."""
        w, h = self.plate_size_m
        return np.array(
            [[-w / 2, -h / 2, 0.0], [w / 2, -h / 2, 0.0], [w / 2, h / 2, 0.0], [-w / 2, h / 2, 0.0]]
        )

    def aruco_dictionary(self) -> cv2.aruco.Dictionary:
        """Return the board's OpenCV dictionary object."""
        return aruco_dictionary(self.dictionary)

    def aruco_board(self) -> cv2.aruco.Board:
        """Return the board as a ``cv2.aruco.Board`` (for drawing or ``matchImagePoints``)."""
        obj = [c.astype(np.float32) for c in self.marker_corners_m]
        return cv2.aruco.Board(obj, self.aruco_dictionary(), self.ids.astype(np.int32))

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """Return the ``board.json`` content as a dict."""
        return {
            "format": BOARD_FORMAT,
            "dictionary": self.dictionary,
            "marker_size_m": self.marker_size_m,
            "plate_size_m": list(self.plate_size_m),
            "markers": [
                {"id": m.id, "corners_m": [list(c) for c in m.corners_m]} for m in self.markers
            ],
        }

    @classmethod
    def from_dict(cls, data: Any) -> Board:
        """Build a board from a ``board.json`` dict, validating every field.

        Raises
        ------
        BoardError
            Unknown or missing keys, wrong types, an unknown dictionary, marker ids out of
            the dictionary, corners that are not a square of ``marker_size_m``, or markers
            outside the plate.
        """
        _check_keys(
            data, {"format", "dictionary", "marker_size_m", "plate_size_m", "markers"}, "board"
        )
        if data["format"] != BOARD_FORMAT:
            raise BoardError(f"format: expected {BOARD_FORMAT!r}, got {data['format']!r}")
        markers_d = data["markers"]
        if not isinstance(markers_d, list):
            raise BoardError(
                f"markers: expected a list of {{id, corners_m}} objects, "
                f"got {type(markers_d).__name__}"
            )
        markers = []
        for k, m in enumerate(markers_d):
            _check_keys(m, {"id", "corners_m"}, f"markers[{k}]")
            markers.append(BoardMarker(m["id"], _marker_corners(m["corners_m"], f"markers[{k}]")))
        return cls(data["dictionary"], data["marker_size_m"], data["plate_size_m"], tuple(markers))

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """Serialise to JSON; write it to ``path`` if given. Returns the text."""
        return dump_json(self.to_dict(), path)

    @classmethod
    def from_json(cls, source: str | os.PathLike) -> Board:
        """Read a board from a ``board.json`` path or from a JSON string."""
        data = load_json_source(source, "board", BoardError)
        return cls.from_dict(data)


def _marker_corners(corners: Any, where: str) -> np.ndarray:
    try:
        arr = np.asarray(corners, dtype=np.float64)
    except (TypeError, ValueError):
        raise BoardError(
            f"{where}.corners_m: expected 4 corners [x, y] in metres, got {corners!r}"
        ) from None
    if arr.shape != (4, 2) or not np.all(np.isfinite(arr)):
        raise BoardError(
            f"{where}.corners_m: expected 4 finite corners [x, y] in metres, got {corners!r}"
        )
    if np.any(np.abs(arr) > MAX_BOARD_EXTENT_M):
        raise BoardError(
            f"{where}.corners_m: expected corners within {MAX_BOARD_EXTENT_M:g} m of the "
            f"plate centre, got {arr.tolist()}"
        )
    return arr


def _check_square(corners: np.ndarray, size_m: float, where: str) -> None:
    sides = np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)
    diagonals = np.linalg.norm(corners[2:] - corners[:2], axis=1)
    tol = _SQUARE_TOL_M + 1e-6 * size_m
    if np.any(np.abs(sides - size_m) > tol) or np.any(
        np.abs(diagonals - size_m * math.sqrt(2)) > tol
    ):
        raise BoardError(
            f"{where}.corners_m: expected a square of side marker_size_m = {size_m:g} m, "
            f"got sides {np.round(sides, 6).tolist()} m"
        )
    # Top-left -> top-right -> bottom-right runs clockwise as printed (y down), which is a
    # positive z cross product in the plate frame.
    e1, e2 = corners[1] - corners[0], corners[2] - corners[1]
    if e1[0] * e2[1] - e1[1] * e2[0] <= 0:
        raise BoardError(
            f"{where}.corners_m: expected the corners clockwise as printed "
            "(top-left, top-right, bottom-right, bottom-left), got them counter-clockwise"
        )


# ---------------------------------------------------------------------- printing
def render_board_image(board: Board, dpi: float = 300.0) -> np.ndarray:
    """Draw the printable plate: ArUco markers on white, at ``dpi`` dots per inch.

    Parameters
    ----------
    board : Board
    dpi : float
        Print resolution. The image spans exactly the plate, so ``board.plate_size_m``
        at ``dpi`` gives its size in pixels (rounded).

    Returns
    -------
    numpy.ndarray, (h, w), uint8
        0 = black, 255 = white. Row 0 is the plate's top edge (y = -h/2).

    Examples
    --------
    >>> img = render_board_image(Board.corner_layout(), dpi=25)
    >>> img.shape, img.dtype, int(img[img.shape[0] // 2, img.shape[1] // 2])
    ((207, 292), dtype('uint8'), 255)
    """
    dpi = _number(dpi, "dpi", positive=True)
    if dpi > MAX_DPI:
        raise BoardError(f"dpi: expected at most {MAX_DPI:g} dots per inch (printers stop "
                         f"well below), got {dpi:g}")
    w_m, h_m = board.plate_size_m
    w_px = max(1, round(w_m / METRES_PER_INCH * dpi))
    h_px = max(1, round(h_m / METRES_PER_INCH * dpi))
    # Separate x and y scales so the image spans the plate exactly despite rounding.
    scale = np.array([w_px / w_m, h_px / h_m])
    plate = np.full((h_px, w_px), 255, np.uint8)
    aruco = board.aruco_dictionary()
    min_side = aruco.markerSize + 2
    side_px = max(min_side, round(board.marker_size_m * float(scale.mean())))
    # Markers are drawn k times finer and averaged down, so an edge that falls inside a
    # pixel gets its coverage as grey level: its position survives to sub-pixel accuracy
    # (nearest-pixel placement would move edges by up to half a pixel).
    k = int(np.clip(math.ceil(_FINE_MARKER_PX / side_px), 1, _MAX_BOARD_SUPERSAMPLE))
    for marker in board.markers:
        # Pixel-edge coordinates on the fine grid: 0 at the plate's left/top edge.
        dst = (np.array(marker.corners_m) + np.array([w_m, h_m]) / 2.0) * scale
        x0, y0 = np.floor(dst.min(axis=0)).astype(int)
        x1, y1 = np.ceil(dst.max(axis=0)).astype(int)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w_px), min(y1, h_px)
        if x1 <= x0 or y1 <= y0:
            continue
        fine_dst = (dst - (x0, y0)) * k
        src = np.array([[0.0, 0.0], [side_px * k, 0.0], [side_px * k, side_px * k]])
        # Both grids put pixel centres at integer coordinates, half a pixel from the edge.
        affine = cv2.getAffineTransform(
            (src - 0.5).astype(np.float32), (fine_dst[:3] - 0.5).astype(np.float32)
        )
        image = cv2.aruco.generateImageMarker(aruco, marker.id, side_px * k)
        fine = cv2.warpAffine(
            image,
            affine,
            ((x1 - x0) * k, (y1 - y0) * k),
            flags=cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=255,
        )
        patch = cv2.resize(fine, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
        # White outside the warped marker, so "darkest wins" pastes it onto the white plate.
        np.minimum(plate[y0:y1, x0:x1], patch, out=plate[y0:y1, x0:x1])
    return plate


def _png_with_dpi(image: np.ndarray, dpi: float) -> bytes:
    ok, encoded = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - cv2 encodes any uint8 image
        raise BoardError("board image: PNG encoding failed")
    data = encoded.tobytes()
    # A pHYs chunk (pixels per metre) makes printers reproduce the plate at its true size.
    ppm = round(dpi / METRES_PER_INCH)
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    end_of_ihdr = 8 + 8 + 13 + 4  # signature, IHDR length+type, IHDR data, CRC
    return data[:end_of_ihdr] + chunk + data[end_of_ihdr:]


def write_board(
    board: Board, out_dir: str | os.PathLike, *, dpi: float = 300.0, overwrite: bool = False
) -> tuple[Path, Path]:
    """Write ``board.png`` (printable, with its resolution stored) and ``board.json``.

    Parameters
    ----------
    board : Board
    out_dir : path
    dpi : float
        Print resolution.
    overwrite : bool
        Replace an existing ``board.png``/``board.json``. Without it they are kept and
        this is an error: a ``board.json`` is often corrected by hand after printing.

    Returns
    -------
    (Path, Path)
        The image path and the JSON path.

    Raises
    ------
    BoardError
        ``board.png`` or ``board.json`` exists and ``overwrite`` is false.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png, js = out / "board.png", out / "board.json"
    there = [p.name for p in (png, js) if p.exists()]
    if there and not overwrite:
        raise BoardError(f"{out}: expected a folder without a board, got {' and '.join(there)} "
                         f"(a hand-corrected board.json would be lost); pass overwrite=True "
                         f"(make-board --force) to replace them")
    write_atomic(png, _png_with_dpi(render_board_image(board, dpi), dpi), error=BoardError)
    board.to_json(js)
    return png, js
