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
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from .._checks import (
    check_image,
    check_keys,
    check_number,
    check_views,
)
from .._json import dump_json, load_json_source
from ..errors import BoardError, LightError
from ..geometry import Plane
from ..imaging import luminance

__all__ = [
    "BOARD_FORMAT",
    "Board",
    "BoardMarker",
    "MarkerDetection",
    "PlatePose",
    "aruco_dictionary",
    "detect_markers",
    "estimate_plate_pose",
    "pose_from_detections",
    "project_points",
    "render_board_image",
    "rotation_from_vector",
    "rotation_to_vector",
    "write_board",
]

BOARD_FORMAT = "srde-board/1"
METRES_PER_INCH = 0.0254
# Corners of a marker must describe a square of the declared size to this tolerance.
_SQUARE_TOL_M = 1e-6
# White quiet zone around each marker in the default layout, as a fraction of its side;
# ArUco needs a light border to find the black marker outline.
_DEFAULT_MARGIN_FRACTION = 0.2
# Markers are drawn on a grid fine enough for about this many pixels per side, at most
# this many times finer than the output.
_FINE_MARKER_PX = 1600
_MAX_BOARD_SUPERSAMPLE = 8
# A plate pose needs the corners of at least this many markers in some view for PnP.
MIN_MARKERS_FOR_PNP = 1
# Largest reprojection error (RMS, px) of a plate pose that is still trusted.
DEFAULT_MAX_REPROJECTION_PX = 2.0


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
    board: Board, out_dir: str | os.PathLike, *, dpi: float = 300.0
) -> tuple[Path, Path]:
    """Write ``board.png`` (printable, with its resolution stored) and ``board.json``.

    Returns
    -------
    (Path, Path)
        The image path and the JSON path.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png, js = out / "board.png", out / "board.json"
    png.write_bytes(_png_with_dpi(render_board_image(board, dpi), dpi))
    board.to_json(js)
    return png, js


# ---------------------------------------------------------------------- detection
@dataclass(frozen=True, eq=False)
class MarkerDetection:
    """The board's markers found in one image.

    Parameters
    ----------
    ids : numpy.ndarray, (K,), int
        Ids of the board markers found (ids not on the board, and ids seen twice, are
        dropped).
    corners_px : numpy.ndarray, (K, 4, 2), float64
        Their corners ``(u, v)`` in OpenCV's order, pixels.
    """

    ids: np.ndarray
    corners_px: np.ndarray

    @property
    def n_markers(self) -> int:
        """Number of board markers found."""
        return int(self.ids.shape[0])

    def correspondences(self, board: Board) -> tuple[np.ndarray, np.ndarray]:
        """Return matched plate points ``(P, 3)`` (metres) and image points ``(P, 2)`` (px)."""
        index = {int(i): k for k, i in enumerate(board.ids)}
        rows = [index[int(i)] for i in self.ids]
        obj = board.marker_corners_m[rows].reshape(-1, 3)
        return obj, self.corners_px.reshape(-1, 2)


def _gray_u8(image: np.ndarray) -> np.ndarray:
    if image.dtype != np.uint8:
        image = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return image


# Marker sides are sampled away from the corners, where the inner bits meet the border.
_EDGE_SPAN = (0.15, 0.85)
_EDGE_STEP_PX = 0.5
_PROFILE_STEP_PX = 0.25
# Half-length of each edge profile, in marker modules: stays inside the black border
# (one module wide) and inside the white quiet zone.
_PROFILE_HALF_MODULES = 0.6
# A refined corner further than this from ArUco's (in modules) means the fit failed.
_MAX_CORNER_SHIFT_MODULES = 1.0
# Edge fits per marker, stopping early once the corners move less than this.
_EDGE_FIT_PASSES = 4
_EDGE_FIT_CONVERGED_PX = 0.01


def _fit_quad(intensity: np.ndarray, quad: np.ndarray, modules: int) -> np.ndarray | None:
    """One pass: lines fitted to the four outer edges near ``quad``, and their corners."""
    side_px = float(np.mean(np.linalg.norm(np.roll(quad, -1, axis=0) - quad, axis=1)))
    half = _PROFILE_HALF_MODULES * side_px / modules
    offsets = np.arange(-half, half + 1e-9, _PROFILE_STEP_PX)
    mid = (offsets[1:] + offsets[:-1]) / 2.0
    centre = quad.mean(axis=0)
    lines = []
    for s in range(4):
        a, b = quad[s], quad[(s + 1) % 4]
        length = float(np.linalg.norm(b - a))
        d = (b - a) / length
        n = np.array([-d[1], d[0]])
        if np.dot(n, (a + b) / 2.0 - centre) < 0:
            n = -n  # outward: from the black border to the white quiet zone
        t = np.arange(_EDGE_SPAN[0] * length, _EDGE_SPAN[1] * length, _EDGE_STEP_PX)
        # (T, S, 2): T points along the side, S samples across it.
        pts = a + t[:, None, None] * d + offsets[None, :, None] * n
        profile = cv2.remap(
            intensity,
            pts[..., 0].astype(np.float32),
            pts[..., 1].astype(np.float32),
            cv2.INTER_LINEAR,
        )
        rise = np.maximum(np.diff(profile, axis=1), 0.0)
        weight = rise.sum(axis=1)
        ok = weight > 0.5 * np.median(weight)
        if ok.sum() < 2:
            return None
        shift = (rise[ok] * mid).sum(axis=1) / weight[ok]
        edge = a + t[ok, None] * d + shift[:, None] * n
        mean = edge.mean(axis=0)
        normal = np.linalg.svd(edge - mean)[2][1]
        lines.append((normal, float(normal @ mean)))
    out = np.empty_like(quad)
    for c in range(4):
        (n1, c1), (n2, c2) = lines[(c - 1) % 4], lines[c]
        system = np.array([n1, n2])
        if abs(np.linalg.det(system)) < 1e-6:
            return None
        out[c] = np.linalg.solve(system, [c1, c2])
    return out


def _refine_marker_corners(intensity: np.ndarray, quads_px: np.ndarray, modules: int) -> np.ndarray:
    """Corners as intersections of lines fitted to sub-pixel edge points of the marker.

    ArUco's own refinements stay 0.3-0.6 px off on markers 30-50 px wide (their corner
    windows see the inner bits) and sometimes leave corners a few pixels off; straight
    lines fitted to the outer black/white edges, located as gradient centroids on
    linear intensity, bring this to a few hundredths of a pixel on rendered views. The
    fit is repeated from its own corners, which recentres the edge profiles.
    """
    out = quads_px.copy()
    for k, quad in enumerate(quads_px):
        module_px = (
            float(np.mean(np.linalg.norm(np.roll(quad, -1, axis=0) - quad, axis=1))) / modules
        )
        current = quad
        for _ in range(_EDGE_FIT_PASSES):
            fitted = _fit_quad(intensity, current, modules)
            if fitted is None:
                break
            moved = float(np.max(np.linalg.norm(fitted - current, axis=1)))
            current = fitted
            if moved < _EDGE_FIT_CONVERGED_PX:
                break
        if np.max(np.linalg.norm(current - quad, axis=1)) <= _MAX_CORNER_SHIFT_MODULES * module_px:
            out[k] = current
    return out


def detect_markers(image: np.ndarray, board: Board, *, encoding: str = "srgb") -> MarkerDetection:
    """Find the board's ArUco markers in one image, with sub-pixel corners.

    Markers come from ``cv2.aruco.ArucoDetector``; their corners are then refined as
    intersections of straight lines fitted to the marker's outer edges (about 0.1 px
    on synthetic views, against 0.3-0.6 px for OpenCV's corner refinements).

    Parameters
    ----------
    image : numpy.ndarray, (H, W) or (H, W, 3), uint8 or float in [0, 1]
        RGB or grey camera image.
    board : Board
    encoding : {"srgb", "linear"}
        How the image encodes intensity; edges are located on linear intensity.

    Returns
    -------
    MarkerDetection
    """
    image = check_image(image)
    aruco = board.aruco_dictionary()
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(aruco, params)
    corners, ids, _ = detector.detectMarkers(_gray_u8(image))
    if ids is None or len(ids) == 0:
        return MarkerDetection(np.zeros(0, np.int64), np.zeros((0, 4, 2)))
    ids = ids.reshape(-1).astype(np.int64)
    corners = np.array(corners, dtype=np.float64).reshape(-1, 4, 2)
    values, counts = np.unique(ids, return_counts=True)
    # A marker id seen twice in one view cannot be matched to one board corner set.
    keep = np.isin(ids, board.ids) & np.isin(ids, values[counts == 1])
    order = np.argsort(ids[keep], kind="stable")
    ids, corners = ids[keep][order], corners[keep][order]
    if ids.size:
        # Black border on each side: the marker spans markerSize + 2 modules.
        corners = _refine_marker_corners(luminance(image, encoding), corners, aruco.markerSize + 2)
    return MarkerDetection(ids, corners)


# ---------------------------------------------------------------------- pose
@dataclass(frozen=True, eq=False)
class PlatePose:
    """The plate's pose in the array frame, and the marker corners it rests on.

    ``X_array = rotation @ X_plate + translation_m``.

    Parameters
    ----------
    rotation : numpy.ndarray, (3, 3), float64
        ``array_from_plate`` rotation.
    translation_m : numpy.ndarray, (3,), float64
        The plate centre in the array frame, metres.
    reprojection_error_px : float
        RMS distance between detected and reprojected marker corners over all views
        used, pixels; NaN for a pose given rather than measured.
    view_errors_px : numpy.ndarray, (N,), float64
        RMS reprojection error per view; NaN for views without markers.
    markers_per_view : tuple of int
        Number of board markers found in each view.
    views_used : tuple of int
        Views whose corners entered the pose.
    plate_points_m : tuple of numpy.ndarray, each (P, 3)
        Per used view, the board corners seen (plate frame, metres).
    image_points_px : tuple of numpy.ndarray, each (P, 2)
        Per used view, where they were detected, pixels.
    """

    rotation: np.ndarray
    translation_m: np.ndarray
    reprojection_error_px: float = math.nan
    view_errors_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    markers_per_view: tuple[int, ...] = ()
    views_used: tuple[int, ...] = ()
    plate_points_m: tuple[np.ndarray, ...] = ()
    image_points_px: tuple[np.ndarray, ...] = ()

    @property
    def center_m(self) -> np.ndarray:
        """The plate centre in the array frame, ``(3,)``, metres."""
        return self.translation_m

    @property
    def normal(self) -> np.ndarray:
        """Unit plate normal on the printed side (plate -z) in the array frame, ``(3,)``."""
        return -self.rotation[:, 2]

    @property
    def plane(self) -> Plane:
        """The plate's plane, normal oriented towards the reference camera (origin)."""
        return Plane.from_point_normal(self.translation_m, self.normal)

    @property
    def has_corners(self) -> bool:
        """Whether the pose carries the marker corners it was measured from."""
        return len(self.views_used) > 0

    def to_array(self, points_plate_m: Any) -> np.ndarray:
        """Map plate-frame points ``(..., 3)`` to the array frame, metres."""
        p = np.asarray(points_plate_m, dtype=np.float64)
        return p @ self.rotation.T + self.translation_m

    def to_plate(self, points_m: Any) -> np.ndarray:
        """Map array-frame points ``(..., 3)`` to the plate frame, metres."""
        p = np.asarray(points_m, dtype=np.float64)
        return (p - self.translation_m) @ self.rotation

    def moved(self, rotation: np.ndarray, translation_m: np.ndarray, rig) -> PlatePose:
        """Return the same measurement at another pose, with its reprojection errors."""
        rms, view_err = _reprojection_errors(
            rotation,
            translation_m,
            rig,
            self.views_used,
            self.plate_points_m,
            self.image_points_px,
            len(self.markers_per_view),
        )
        return replace(
            self,
            rotation=rotation,
            translation_m=translation_m,
            reprojection_error_px=rms,
            view_errors_px=view_err,
        )

    @classmethod
    def from_center_normal(
        cls, center_m: Any, normal: Any, *, rotation_rad: float = 0.0
    ) -> PlatePose:
        """Build a pose from the plate centre and the normal of its printed side.

        The normal is flipped to face the array origin if needed. The plate's x axis is
        the array x axis projected onto the plate (the y axis if the normal is within
        about 25 deg of x), turned by ``rotation_rad`` about the normal (positive turns
        x towards y). This is a given pose, not a measurement: it carries no corners.
        """
        c = np.asarray(center_m, dtype=np.float64)
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        if np.dot(n, -c) < 0:
            n = -n
        z = -n
        # The same in-plane axes as the renderer's planar objects (srde_fusion.synthetic):
        # the array x axis projected onto the plate, or y when the plate faces along x.
        ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = ref - np.dot(ref, n) * n
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        cos, sin = math.cos(rotation_rad), math.sin(rotation_rad)
        x, y = cos * x + sin * y, -sin * x + cos * y
        return cls(np.stack([x, y, z], axis=1), c)


def project_points(rig, points_m: np.ndarray, cameras: Any) -> np.ndarray:
    """Project array-frame points ``(P, 3)``, each into its own camera ``(P,)``, pixels."""
    rel = points_m - rig.centers_m[cameras]
    k = rig.intrinsics
    return np.stack(
        [k.fx * rel[:, 0] / rel[:, 2] + k.cx, k.fy * rel[:, 1] / rel[:, 2] + k.cy], axis=1
    )


def rotation_from_vector(rvec: Any) -> np.ndarray:
    """Rotation matrix ``(3, 3)`` of a Rodrigues vector ``(3,)``."""
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]


def rotation_to_vector(rotation: np.ndarray) -> np.ndarray:
    """Rodrigues vector ``(3,)`` of a rotation matrix ``(3, 3)``."""
    return cv2.Rodrigues(np.asarray(rotation, dtype=np.float64))[0].ravel()


def _reprojection_errors(rotation, translation_m, rig, views, plate_points, image_points, n_views):
    view_err = np.full(n_views, np.nan)
    squares = []
    for i, obj, img in zip(views, plate_points, image_points, strict=True):
        d2 = np.sum((project_points(rig, obj @ rotation.T + translation_m, i) - img) ** 2, axis=1)
        view_err[i] = float(np.sqrt(d2.mean()))
        squares.append(d2)
    rms = float(np.sqrt(np.concatenate(squares).mean())) if squares else math.nan
    return rms, view_err


def estimate_plate_pose(
    views: Sequence[np.ndarray],
    rig,
    board: Board,
    *,
    min_views: int = 1,
    min_markers: int = 1,
    max_reprojection_px: float = DEFAULT_MAX_REPROJECTION_PX,
) -> PlatePose:
    """Estimate one pose of the plate in the array frame from the markers of all views.

    Each view with at least ``min_markers`` markers contributes its corners. The pose
    is initialised by planar PnP (both IPPE solutions) in the view with the most
    markers and refined by Levenberg-Marquardt over the 6 degrees of freedom on the
    corners of all those views together (cameras differ only by their centres).

    Parameters
    ----------
    views : sequence of numpy.ndarray, (H, W, 3) or (H, W)
        One image per rig camera, in rig order.
    rig : CameraRig
    board : Board
    min_views : int
        Views with markers needed.
    min_markers : int
        Markers a view needs to count.
    max_reprojection_px : float
        Largest RMS reprojection error accepted, pixels.

    Returns
    -------
    PlatePose

    Raises
    ------
    LightError
        Markers in too few views (the message lists how many each view had), or
        corners that no single plate pose explains.
    """
    views = check_views(views, rig.n_cameras, rig.image_size)
    detections = [detect_markers(v, board, encoding=rig.image_encoding) for v in views]
    return pose_from_detections(
        detections,
        rig,
        board,
        min_views=min_views,
        min_markers=min_markers,
        max_reprojection_px=max_reprojection_px,
    )


def pose_from_detections(
    detections: Sequence[MarkerDetection],
    rig,
    board: Board,
    *,
    min_views: int = 1,
    min_markers: int = 1,
    max_reprojection_px: float = DEFAULT_MAX_REPROJECTION_PX,
) -> PlatePose:
    """Solve the joint plate pose from per-view marker detections.

    See :func:`estimate_plate_pose` for the parameters.
    """
    counts = tuple(d.n_markers for d in detections)
    used = tuple(i for i, c in enumerate(counts) if c >= max(min_markers, MIN_MARKERS_FOR_PNP))
    if len(used) < min_views:
        listing = ", ".join(f"{rig.camera_names[i]}: {c}" for i, c in enumerate(counts))
        raise LightError(
            f"plate markers: expected at least {min_markers} of the board's "
            f"{len(board.markers)} markers in at least {min_views} views, got them in "
            f"{len(used)} (markers per view: {listing})"
        )
    pairs = [detections[i].correspondences(board) for i in used]
    obj = tuple(p[0] for p in pairs)
    img = tuple(p[1] for p in pairs)
    # (P,) camera index of every corner, so one projection covers all views.
    cameras = np.concatenate([np.full(o.shape[0], i) for i, o in zip(used, obj, strict=True)])
    obj_all, img_all = np.concatenate(obj), np.concatenate(img)

    def residuals(params: np.ndarray) -> np.ndarray:
        r, t = rotation_from_vector(params[:3]), params[3:]
        return (project_points(rig, obj_all @ r.T + t, cameras) - img_all).ravel()

    best = used.index(max(used, key=lambda i: counts[i]))
    n_sol, rvecs, tvecs, _ = cv2.solvePnPGeneric(
        obj[best], img[best], rig.intrinsics.matrix, None, flags=cv2.SOLVEPNP_IPPE
    )
    if n_sol == 0:
        raise LightError(
            f"plate pose: PnP found no pose from the {counts[used[best]]} markers of view "
            f"{rig.camera_names[used[best]]}"
        )
    fits = []
    # Planar PnP has two mirror-like solutions; all views together tell them apart.
    for rvec, tvec in zip(rvecs, tvecs, strict=True):
        # The view's camera frame is the array frame shifted by the camera centre.
        start = np.concatenate([np.ravel(rvec), np.ravel(tvec) + rig.centers_m[used[best]]])
        fits.append(least_squares(residuals, start, method="lm", x_scale="jac"))
    fit = min(fits, key=lambda f: f.cost)
    rotation, translation = rotation_from_vector(fit.x[:3]), fit.x[3:]
    rms, view_err = _reprojection_errors(
        rotation, translation, rig, used, obj, img, len(detections)
    )
    if not rms <= max_reprojection_px:
        worst = used[int(np.nanargmax(view_err[list(used)]))]
        raise LightError(
            f"plate pose: expected marker corners consistent with one plate pose "
            f"(RMS reprojection error <= {max_reprojection_px:g} px), got "
            f"{rms:.2f} px (worst view {rig.camera_names[worst]}: "
            f"{view_err[worst]:.2f} px)"
        )
    return PlatePose(rotation, translation, rms, view_err, counts, used, obj, img)
