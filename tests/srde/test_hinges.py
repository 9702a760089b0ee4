"""Hinge planes: a face's plane from its neighbour's plane and their shared edge."""

import math

import cv2
import numpy as np
import pytest

from srde_fusion.geometry import Plane, plane_disparity, project_points
from srde_fusion.srde.assignment import box_corners, plane_gap_px, reflection_points
from srde_fusion.srde.hinges import hinge_chords, hinge_plane, outline_corners
from srde_fusion.synthetic import default_rig
from srde_fusion.synthetic.faceted import _rotate


class _TwoFaces:
    """Two flat faces sharing an edge, their outline in the reference view and lights.

    Face A is a plane facing the cameras; face B is A turned about the shared edge (a
    3-D line on A) by ``angle_deg``. Each face is a parallelogram ``width_m`` across the
    edge; light 0 is placed so that A mirrors it near A's middle, light 1 so that B
    mirrors it near B's middle (both from the reference camera).
    """

    def __init__(self, rig, angle_deg: float, *, depth_m=0.9, tilt_deg=12.0,
                 edge_m=0.24, width_m=0.12):
        self.rig = rig
        centre = np.array([0.01, -0.02, depth_m])
        tilt_axis = np.array([0.3, 1.0, 0.0]) / math.hypot(0.3, 1.0)
        normal_a = _rotate(np.array([0.0, 0.0, -1.0]), tilt_axis, math.radians(tilt_deg))
        edge_dir = np.cross(normal_a, np.array([1.0, 0.0, 0.0]))
        edge_dir /= np.linalg.norm(edge_dir)
        across_a = np.cross(normal_a, edge_dir)  # in A, away from the edge
        if across_a[0] > 0:
            across_a = -across_a
        normal_b = _rotate(normal_a, edge_dir, math.radians(angle_deg))
        across_b = np.cross(edge_dir, normal_b)
        if across_b @ across_a > 0:
            across_b = -across_b
        self.ends_m = np.stack([centre - 0.5 * edge_m * edge_dir, centre + 0.5 * edge_m * edge_dir])
        self.a = Plane.from_point_normal(centre, normal_a, rig.reference_center_m)
        self.b = Plane.from_point_normal(centre, normal_b, rig.reference_center_m)
        far_a = self.ends_m + width_m * across_a
        far_b = self.ends_m + width_m * across_b
        # Outline round both faces: far side of A, far side of B.
        self.vertices_m = np.stack([far_a[0], self.ends_m[0], far_b[0], far_b[1],
                                    self.ends_m[1], far_a[1]])
        self.vertices_uv = rig.project(self.vertices_m)
        scale = 16  # fillPoly's sub-pixel vertices (shift 4)
        self.mask = np.zeros((rig.height, rig.width), np.uint8)
        # Pixel centres are at integer coordinates: a pixel is in when its centre is.
        cv2.fillPoly(self.mask, [np.rint(self.vertices_uv * scale).astype(np.int32)], 1,
                     lineType=cv2.LINE_8, shift=4)
        self.mask = self.mask.astype(bool)
        mid_a = centre + 0.5 * width_m * across_a
        mid_b = centre + 0.5 * width_m * across_b
        self.lights_m = np.stack([self._light_over(self.a, mid_a), self._light_over(self.b, mid_b)])

    def _light_over(self, plane, point_m):
        """A light that ``plane`` mirrors into the reference camera at ``point_m``."""
        to_camera = self.rig.reference_center_m - point_m
        to_camera /= np.linalg.norm(to_camera)
        n = plane.n
        out = 2.0 * float(n @ to_camera) * n - to_camera
        return point_m + 0.8 * out

    def highlights_uv(self, plane, light):
        """The light's highlight in every view ``(N, 2)`` as ``plane`` mirrors it."""
        virtual = plane.mirror(self.lights_m[light])
        return project_points(self.rig, virtual, np.arange(self.rig.n_cameras))

    def mirror_points_uv(self, plane, light):
        """Where ``plane`` reflects the light towards each camera, seen from the reference."""
        points, _ = reflection_points(plane, plane.mirror(self.lights_m[light]),
                                      self.rig.centers_m)
        return self.rig.project(points)

    def seen_beyond_edge(self, plane, light):
        """Views whose mirror point of the light lies on the object beyond the edge from A."""
        uv = self.mirror_points_uv(plane, light)
        u, v = np.rint(uv).astype(int).T
        inside = (u >= 0) & (u < self.rig.width) & (v >= 0) & (v < self.rig.height)
        on = np.zeros(len(uv), bool)
        on[inside] = self.mask[v[inside], u[inside]]
        p0, p1 = self.rig.project(self.ends_m)
        normal = np.array([p0[1] - p1[1], p1[0] - p0[0]])
        a_side = np.sign((self.mirror_points_uv(self.a, 0) - p0) @ normal)[0]
        return int(np.count_nonzero(on & (np.sign((uv - p0) @ normal) == -a_side)))

    def gap_px(self, p, q):
        return plane_gap_px(self.rig, box_corners(self.mask), p, q)


@pytest.fixture(scope="module")
def rig():
    return default_rig()


@pytest.mark.parametrize("angle_deg", [-35.0, -15.0, 25.0, 50.0])
def test_the_turned_plane_through_the_true_edge_is_the_face_s(rig, angle_deg):
    faces = _TwoFaces(rig, angle_deg)
    chord = tuple(rig.project(faces.ends_m))
    # Each view sees B's highlight of light 1 and A's of light 0 (a distractor for B).
    cands = [np.stack([faces.highlights_uv(faces.b, 1)[j], faces.highlights_uv(faces.a, 0)[j]])
             for j in range(rig.n_cameras)]
    found = hinge_plane(rig, faces.lights_m, faces.mask, faces.a, chord,
                        faces.mirror_points_uv(faces.a, 0), cands, (2.0, 8.0))
    # Views where B reflects light 1 on the object, beyond the edge (a steep B sends some
    # off it) explain it; A's highlights lie on A's side.
    assert len(found) == 2
    for plane, explained in found:
        assert explained == faces.seen_beyond_edge(faces.b, 1) >= 5
        assert faces.gap_px(plane, faces.b) < 0.01


def test_centres_a_few_pixels_off_still_give_the_face_s_plane(rig):
    faces = _TwoFaces(rig, 35.0)
    chord = tuple(rig.project(faces.ends_m))
    rng = np.random.default_rng(3)
    truth = faces.highlights_uv(faces.b, 1)
    cands = [truth[j][None] + rng.normal(0.0, 1.5, 2) for j in range(rig.n_cameras)]
    found = hinge_plane(rig, faces.lights_m, faces.mask, faces.a, chord,
                        faces.mirror_points_uv(faces.a, 0), cands, (2.0, 8.0))
    # Three parameters from nine centres 1.5 px off, against one angle from them: the
    # plane fitted to the centres lies farther off than the turned one.
    assert found and faces.gap_px(found[-1][0], faces.b) < 0.3


def test_the_outline_s_corners_are_the_faces_corners(rig):
    # (B turned towards the cameras: every corner turns the outline by degrees. Turned
    # away, the sides across the edge run nearly straight on in the image, and where
    # along them the bend lies is known to several pixels only.)
    faces = _TwoFaces(rig, -25.0)
    corners = outline_corners(faces.mask)
    assert len(corners) == len(faces.vertices_uv)
    nearest = np.min(np.linalg.norm(corners[:, None] - faces.vertices_uv[None], axis=2), axis=1)
    assert np.max(nearest) < 1.0


def test_the_edge_is_a_chord_and_the_outline_s_sides_are_not(rig):
    faces = _TwoFaces(rig, -25.0)
    corners = outline_corners(faces.mask)
    chords = hinge_chords(faces.mask, corners)
    edge = rig.project(faces.ends_m)

    def near(p, q):
        return np.hypot(*(p - q)) < 1.0

    assert any((near(p, edge[0]) and near(q, edge[1])) or (near(p, edge[1]) and near(q, edge[0]))
               for p, q in chords)
    m = len(corners)
    sides = {(i, (i + 1) % m) for i in range(m)}
    for p, q in chords:
        i = int(np.argmin(np.linalg.norm(corners - p, axis=1)))
        j = int(np.argmin(np.linalg.norm(corners - q, axis=1)))
        assert (i, j) not in sides and (j, i) not in sides


def test_the_turned_plane_from_the_outline_s_corners_is_near_the_face_s(rig):
    faces = _TwoFaces(rig, -30.0)
    corners = outline_corners(faces.mask)
    cands = [faces.highlights_uv(faces.b, 1)[j][None] for j in range(rig.n_cameras)]
    source_uv = faces.mirror_points_uv(faces.a, 0)
    planes = [plane for chord in hinge_chords(faces.mask, corners)
              for plane, _ in hinge_plane(rig, faces.lights_m, faces.mask, faces.a, chord,
                                          source_uv, cands, (2.0,))]
    assert min(faces.gap_px(p, faces.b) for p in planes) < 0.25
    # The disparity over face B's part is then within the same bound.
    best = min(planes, key=lambda p: faces.gap_px(p, faces.b))
    assert np.max(np.abs(plane_disparity(best, rig) - plane_disparity(faces.b, rig))[faces.mask]) \
        < 0.25


def test_a_chord_with_the_source_s_highlights_on_both_sides_turns_nothing(rig):
    faces = _TwoFaces(rig, 30.0)
    chord = tuple(rig.project(faces.ends_m))
    cands = [faces.highlights_uv(faces.b, 1)[j][None] for j in range(rig.n_cameras)]
    both_sides = np.concatenate([faces.mirror_points_uv(faces.a, 0),
                                 faces.mirror_points_uv(faces.b, 1)])
    assert hinge_plane(rig, faces.lights_m, faces.mask, faces.a, chord, both_sides, cands,
                       (2.0,)) == []


def test_no_candidate_beyond_the_edge_turns_nothing(rig):
    faces = _TwoFaces(rig, 30.0)
    chord = tuple(rig.project(faces.ends_m))
    cands = [faces.highlights_uv(faces.a, 0)[j][None] for j in range(rig.n_cameras)]
    assert hinge_plane(rig, faces.lights_m, faces.mask, faces.a, chord,
                       faces.mirror_points_uv(faces.a, 0), cands, (2.0, 8.0)) == []
