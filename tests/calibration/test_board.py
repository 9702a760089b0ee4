"""Tests of the ArUco calibration plate: layout, board.json, printing, markers, pose."""

from __future__ import annotations

import json
import math
import struct

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from srde_fusion.calibration import (
    BOARD_FORMAT,
    Board,
    BoardMarker,
    PlatePose,
    detect_markers,
    estimate_plate_pose,
    render_board_image,
    write_board,
)
from srde_fusion.cli import main
from srde_fusion.errors import BoardError, LightError
from srde_fusion.geometry import project_points
from srde_fusion.synthetic import PlanarObject, highlight_normal, plate_scene, render

LIGHT_M = np.array([0.15, -0.35, 0.1])
# Tolerances measured on renderings with 2x2 supersampling (see test bodies).
CORNER_RMS_TOL_PX = 0.15
POSE_CENTER_TOL_M = 1e-3
POSE_NORMAL_TOL_RAD = 1e-3


@pytest.fixture(scope="module")
def board() -> Board:
    return Board.corner_layout()


# ---------------------------------------------------------------------- layout and JSON
def test_corner_layout_puts_one_marker_in_each_corner_and_leaves_the_centre_free(board):
    assert board.ids.tolist() == [0, 1, 2, 3]
    centres = board.marker_corners_m.mean(axis=1)
    w, h = board.plate_size_m
    # top-left, top-right, bottom-right, bottom-left, in plate coordinates (y down)
    assert np.array_equal(np.sign(centres[:, :2]), [[-1, -1], [1, -1], [1, 1], [-1, 1]])
    margin = 0.2 * board.marker_size_m
    assert np.isclose(board.marker_corners_m[0, 0, 0], -w / 2 + margin)
    assert np.isclose(board.marker_corners_m[2, 2, 1], h / 2 - margin)
    # no marker reaches into the central band
    assert np.all(np.abs(board.marker_corners_m[..., 0]) > 0.05)


def test_board_json_round_trip_through_text_and_file(board, tmp_path):
    again = Board.from_json(board.to_json())
    assert again == board
    path = tmp_path / "board.json"
    board.to_json(path)
    assert Board.from_json(path) == board
    assert json.loads(path.read_text())["format"] == BOARD_FORMAT


@given(
    marker_mm=st.floats(20, 80),
    extra_w=st.floats(10, 200),
    extra_h=st.floats(10, 200),
    first_id=st.integers(0, 40),
)
def test_board_json_round_trip_property(marker_mm, extra_w, extra_h, first_id):
    size = marker_mm / 1000
    plate = (2.4 * size + extra_w / 1000, 2.4 * size + extra_h / 1000)
    board = Board.corner_layout(marker_size_m=size, plate_size_m=plate, first_id=first_id)
    assert Board.from_json(board.to_json()) == board


def _edit(board: Board, **changes) -> str:
    data = board.to_dict()
    data.update(changes)
    return json.dumps(data)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"colour": "white"}, r"board: unknown key\(s\) \['colour'\]"),
        ({"format": "srde-board/9"}, r"format: expected 'srde-board/1'"),
        ({"dictionary": "DICT_9X9_1"}, r"dictionary: expected an OpenCV ArUco dictionary name"),
        ({"marker_size_m": -0.05}, r"marker_size_m: expected a positive number"),
        ({"marker_size_m": "5cm"}, r"marker_size_m: expected a number, got str"),
        ({"plate_size_m": [0.3]}, r"plate_size_m: expected \[width, height\]"),
        ({"markers": {}}, r"markers: expected a list"),
        ({"markers": []}, r"markers: expected at least one marker"),
    ],
)
def test_board_json_errors_name_the_field(board, change, message):
    with pytest.raises(BoardError, match=message):
        Board.from_json(_edit(board, **change))


def test_board_json_marker_errors(board):
    data = board.to_dict()
    data["markers"][1]["rotation"] = 0
    with pytest.raises(BoardError, match=r"markers\[1\]: unknown key\(s\) \['rotation'\]"):
        Board.from_dict(data)
    data = board.to_dict()
    del data["markers"][2]["corners_m"]
    with pytest.raises(BoardError, match=r"markers\[2\]: missing key\(s\) \['corners_m'\]"):
        Board.from_dict(data)
    data = board.to_dict()
    data["markers"][0]["id"] = 50
    with pytest.raises(BoardError, match=r"markers\[0\]\.id: expected an integer in \[0, 49\]"):
        Board.from_dict(data)
    data = board.to_dict()
    data["markers"][3]["id"] = 0
    with pytest.raises(BoardError, match=r"markers\[3\]\.id: expected unique marker ids, got 0"):
        Board.from_dict(data)
    data = board.to_dict()
    data["markers"][0]["corners_m"][1][0] += 0.001
    with pytest.raises(BoardError, match=r"markers\[0\]\.corners_m: expected a square of side"):
        Board.from_dict(data)
    data = board.to_dict()
    data["markers"][0]["corners_m"] = data["markers"][0]["corners_m"][::-1]
    with pytest.raises(BoardError, match=r"clockwise as printed"):
        Board.from_dict(data)
    data = board.to_dict()
    data["markers"][0]["corners_m"] = [[x - 0.2, y] for x, y in data["markers"][0]["corners_m"]]
    with pytest.raises(BoardError, match=r"markers\[0\]\.corners: expected the marker inside"):
        Board.from_dict(data)
    data = board.to_dict()
    data["markers"][0]["corners_m"] = [[0, 0], [1, 0]]
    with pytest.raises(BoardError, match=r"markers\[0\]\.corners_m: expected 4 finite corners"):
        Board.from_dict(data)


def test_board_file_errors(tmp_path):
    with pytest.raises(BoardError, match="expected an existing board.json"):
        Board.from_json(tmp_path / "missing.json")
    with pytest.raises(BoardError, match="expected valid JSON"):
        Board.from_json("{not json")


def test_corner_layout_rejects_a_plate_too_small_for_its_markers():
    with pytest.raises(BoardError, match=r"plate_size_m: expected a plate larger than 0.12 m"):
        Board.corner_layout(marker_size_m=0.05, plate_size_m=(0.3, 0.1))
    with pytest.raises(BoardError, match="margin_m: expected a non-negative number"):
        Board.corner_layout(margin_m=-0.01)


def test_rotated_marker_is_valid():
    c, s = math.cos(0.3), math.sin(0.3)
    square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 0.02
    corners = square @ np.array([[c, s], [-s, c]])
    board = Board("DICT_4X4_50", 0.04, (0.2, 0.2), (BoardMarker(7, corners.tolist()),))
    assert board.ids.tolist() == [7]


# ---------------------------------------------------------------------- printing
def test_render_board_image_places_markers_where_the_board_says(board):
    dpi = 72.0
    image = render_board_image(board, dpi)
    w, h = board.plate_size_m
    assert image.shape == (round(h / 0.0254 * dpi), round(w / 0.0254 * dpi))
    assert image.dtype == np.uint8
    assert image[image.shape[0] // 2, image.shape[1] // 2] == 255
    # The image is a fronto-parallel "photo" of the plate: detection must find each
    # marker's corners at its board position, converted to pixels.
    found = detect_markers(image, board, encoding="linear")
    assert found.ids.tolist() == [0, 1, 2, 3]
    scale = np.array([image.shape[1] / w, image.shape[0] / h])
    expected = (board.marker_corners_m[..., :2] + np.array([w, h]) / 2) * scale - 0.5
    assert np.abs(found.corners_px - expected).max() < 0.05


def test_write_board_stores_the_print_resolution(board, tmp_path):
    png, js = write_board(board, tmp_path / "out", dpi=150)
    assert Board.from_json(js) == board
    data = png.read_bytes()
    at = data.index(b"pHYs")
    ppm_x, ppm_y, unit = struct.unpack(">IIB", data[at + 4 : at + 13])
    assert (ppm_x, ppm_y, unit) == (round(150 / 0.0254), round(150 / 0.0254), 1)
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(decoded, render_board_image(board, 150))


def test_render_board_image_rejects_bad_dpi(board):
    with pytest.raises(BoardError, match="dpi: expected a positive number"):
        render_board_image(board, 0)


def test_make_board_command(tmp_path, capsys):
    out = tmp_path / "plate"
    code = main(
        [
            "make-board",
            str(out),
            "--dpi",
            "50",
            "--marker-size-mm",
            "40",
            "--plate-size-mm",
            "200",
            "150",
            "--first-id",
            "10",
        ]
    )
    assert code == 0
    board = Board.from_json(out / "board.json")
    assert board.ids.tolist() == [10, 11, 12, 13]
    assert board.plate_size_m == (0.2, 0.15)
    assert math.isclose(board.marker_size_m, 0.04)
    assert (out / "board.png").is_file()
    assert "4 markers [10, 11, 12, 13]" in capsys.readouterr().out
    assert main(["make-board", str(out), "--dictionary", "DICT_NOPE"]) == 2
    assert "dictionary: expected an OpenCV ArUco dictionary" in capsys.readouterr().err


# ---------------------------------------------------------------------- detection
def test_detect_markers_ignores_markers_of_other_boards(board):
    other = Board.corner_layout(first_id=4)
    image = render_board_image(other, 72)
    assert detect_markers(image, board).n_markers == 0
    assert detect_markers(image, other).ids.tolist() == [4, 5, 6, 7]


def test_detect_markers_drops_an_id_seen_twice(board):
    image = render_board_image(board, 72)
    doubled = np.concatenate([image, image], axis=1)
    assert detect_markers(doubled, board).n_markers == 0


# ---------------------------------------------------------------------- pose
@pytest.mark.parametrize(
    "normal", [(0.0, 0.0, -1.0), (0.3, -0.4, -1.0), (-0.95, 0.1, -0.3), (0.2, 0.97, -0.2)]
)
@pytest.mark.parametrize("rotation_rad", [0.0, 0.7, -2.0])
def test_plate_frame_matches_the_renderer_texture_axes(normal, rotation_rad):
    center = (0.05, -0.02, 0.9)
    pose = PlatePose.from_center_normal(center, normal, rotation_rad=rotation_rad)
    obj = PlanarObject("rectangle", center, normal, (0.3, 0.2), rotation_rad=rotation_rad)
    e1, e2 = obj.axes
    # plate x = texture columns, plate y = texture rows (down), printed side to the camera
    assert np.allclose(pose.rotation[:, 0], e1)
    assert np.allclose(pose.rotation[:, 1], e2)
    assert np.allclose(pose.normal, obj.normal)
    assert np.allclose(np.linalg.det(pose.rotation), 1.0)


@given(
    st.lists(st.floats(-1, 1), min_size=3, max_size=3),
    st.floats(-3, 3),
    st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
)
def test_plate_pose_round_trip(normal_xy, rotation_rad, points):
    normal = np.array(normal_xy) + [0.0, 0.0, -2.5]
    pose = PlatePose.from_center_normal([0.1, 0.0, 1.0], normal, rotation_rad=rotation_rad)
    p = np.array(points)
    assert np.allclose(pose.to_plate(pose.to_array(p)), p)
    on_plate = pose.to_array([p[0], p[1], 0.0])
    assert abs(pose.plane.signed_distance(on_plate)) < 1e-12


@pytest.fixture(scope="module")
def rendered_plate(rig3x3, board):
    center = np.array([0.04, 0.03, 0.95])
    normal = highlight_normal(center + [0.02, 0.0, 0.0], LIGHT_M)
    scene = plate_scene(board, rig3x3, LIGHT_M, center_m=center, normal=normal, rotation_rad=0.25)
    views = render(scene, rig3x3, supersample=2).views
    return views, PlatePose.from_center_normal(center, normal, rotation_rad=0.25)


def test_marker_corners_are_sub_pixel_on_rendered_views(rendered_plate, rig3x3, board):
    views, truth = rendered_plate
    errors = []
    for i in (0, 4, 8):
        found = detect_markers(views[i], board)
        assert found.n_markers == 4
        obj, img = found.correspondences(board)
        errors.append(img - project_points(rig3x3, truth.to_array(obj), np.full(len(obj), i)))
    rms = float(np.sqrt(np.mean(np.sum(np.concatenate(errors) ** 2, axis=1))))
    # measured about 0.03 px; OpenCV's own corner refinement gives 0.3-0.6 px here
    assert rms < CORNER_RMS_TOL_PX


def test_estimate_plate_pose_uses_every_view(rendered_plate, rig3x3, board):
    views, truth = rendered_plate
    pose = estimate_plate_pose(views, rig3x3, board)
    assert pose.views_used == tuple(range(9))
    assert pose.markers_per_view == (4,) * 9
    assert pose.reprojection_error_px < CORNER_RMS_TOL_PX
    assert np.all(pose.view_errors_px < 2 * CORNER_RMS_TOL_PX)
    assert np.linalg.norm(pose.center_m - truth.center_m) < POSE_CENTER_TOL_M
    # measured 0.1-0.3 mrad: the tilt of a small plate is its least-known part
    angle = math.acos(min(1.0, float(pose.normal @ truth.normal)))
    assert angle < POSE_NORMAL_TOL_RAD
    assert np.allclose(pose.rotation[:, 0], truth.rotation[:, 0], atol=2e-3)


def test_estimate_plate_pose_reports_markers_per_view(rendered_plate, rig3x3, board):
    views, _ = rendered_plate
    blank = np.zeros_like(views[0])
    partial = [blank] * 7 + list(views[7:])
    with pytest.raises(
        LightError,
        match=r"in at least 3 views, got them in 2 \(markers per view: "
        r"cam0: 0, .* cam7: 4, cam8: 4\)",
    ):
        estimate_plate_pose(partial, rig3x3, board, min_views=3)
    pose = estimate_plate_pose(partial, rig3x3, board)
    assert pose.views_used == (7, 8)
    assert np.isnan(pose.view_errors_px[0])


def test_estimate_plate_pose_rejects_a_board_that_does_not_fit(rendered_plate, rig3x3, board):
    views, _ = rendered_plate
    # Same ids, wrong geometry: the markers printed 20 % larger than declared.
    wrong = Board.corner_layout(marker_size_m=0.06, margin_m=0.002)
    with pytest.raises(
        LightError,
        match=r"plate pose: expected marker corners consistent with one "
        r"plate pose \(RMS reprojection error <= 2 px\), got",
    ):
        estimate_plate_pose(views, rig3x3, wrong)


def test_make_board_keeps_an_existing_board_unless_forced(tmp_path, capsys):
    assert main(["make-board", str(tmp_path), "--dpi", "50"]) == 0
    edited = (tmp_path / "board.json").read_text().replace("0.05", "0.0498")
    (tmp_path / "board.json").write_text(edited)
    capsys.readouterr()
    assert main(["make-board", str(tmp_path), "--dpi", "50"]) == 2
    assert "got board.png and board.json (a hand-corrected board.json would be lost)" in \
        capsys.readouterr().err
    assert (tmp_path / "board.json").read_text() == edited
    assert main(["make-board", str(tmp_path), "--dpi", "50", "--force"]) == 0
    assert (tmp_path / "board.json").read_text() != edited


def test_board_dpi_is_capped():
    with pytest.raises(BoardError, match="dpi: expected at most 4800 dots per inch"):
        render_board_image(Board.corner_layout(), dpi=1e6)


def test_board_sizes_in_millimetres_are_refused():
    data = Board.corner_layout().to_dict()
    data["plate_size_m"] = [297.0, 210.0]
    with pytest.raises(BoardError, match=r"plate_size_m: expected a plate at most 10 m wide"):
        Board.from_dict(data)
    data = Board.corner_layout().to_dict()
    data["markers"][0]["corners_m"][0] = [1e308, 0.0]
    with pytest.raises(BoardError, match=r"markers\[0\].corners_m: expected corners within 10 m"):
        Board.from_dict(data)
