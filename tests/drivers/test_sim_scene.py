"""Simulator geometry against analytic answers: rays vs plane, box, cylinder, cone, sphere, textured plane;
nearest hit (occlusion) and shadow segments."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.models import rotation_from_euler_deg
from drivers.sim import Box, Cone, Cylinder, Plane, Scene, Sphere, TexturedPlane, intersect_scene, segment_blocked

O = np.zeros((1, 3))


def _one(obj, o, d):
    t, n = obj.intersect(np.asarray(o, float).reshape(-1, 3), np.asarray(d, float).reshape(-1, 3))
    return float(t[0]), n[0]


def test_ray_hits_plane_at_the_analytic_point():
    plane = Plane((0, 0, 100), (0, 0, -1))
    d = np.array([0.1, 0.2, 1.0])
    t, n = _one(plane, O, d)
    assert t == pytest.approx(100.0)
    np.testing.assert_allclose(t * d, [10, 20, 100])
    np.testing.assert_allclose(n, [0, 0, -1])
    # parallel and backwards rays miss
    assert _one(plane, O, [1, 0, 0])[0] == np.inf
    assert _one(plane, O, [0, 0, -1])[0] == np.inf


def test_ray_hits_rotated_box_faces():
    R = rotation_from_euler_deg(10, 20, 30)
    box = Box((5, -3, 200), (20, 40, 60), R)
    c = np.array([5.0, -3.0, 200.0])
    for axis, half in ((0, 10), (1, 20), (2, 30)):
        e = R[:, axis]
        o = c - 100 * e
        t, n = _one(box, o, e)
        assert t == pytest.approx(100 - half)
        np.testing.assert_allclose(n, -e, atol=1e-12)
        # from the other side: the opposite face
        t, n = _one(box, c + 100 * e, -e)
        assert t == pytest.approx(100 - half)
        np.testing.assert_allclose(n, e, atol=1e-12)
    # a ray passing just outside the 20 mm face misses, just inside hits
    e0, e1 = R[:, 0], R[:, 1]
    assert _one(box, c - 100 * e0 + 20.01 * e1, e0)[0] == np.inf
    assert _one(box, c - 100 * e0 + 19.99 * e1, e0)[0] == pytest.approx(90)


def test_ray_hits_cylinder_side_and_cap():
    cyl = Cylinder((0, 0, 100), (0, 0, -1), radius_mm=10, height_mm=30)  # stands on z = 100, top at z = 70
    t, n = _one(cyl, (-50, 0, 90), (1, 0, 0))
    assert t == pytest.approx(40)
    np.testing.assert_allclose(n, [-1, 0, 0], atol=1e-12)
    # oblique ray onto the side: x = −50 + t, y = 6 → hits where x² + 36 = 100, x = −8
    t, n = _one(cyl, (-50, 6, 80), (1, 0, 0))
    assert t == pytest.approx(42)
    np.testing.assert_allclose(n, [-0.8, 0.6, 0], atol=1e-12)
    t, n = _one(cyl, O, (0.05, 0.0, 1.0))  # straight down onto the top cap at z = 70
    assert t == pytest.approx(70)
    np.testing.assert_allclose(n, [0, 0, -1], atol=1e-12)
    assert _one(cyl, (-50, 0, 65), (1, 0, 0))[0] == np.inf  # above the top
    assert _one(cyl, (-50, 10.5, 90), (1, 0, 0))[0] == np.inf  # beside it


def test_ray_hits_cone_side_apex_region_and_base():
    cone = Cone((0, 0, 100), (0, 0, -1), radius_mm=10, height_mm=20)  # apex at z = 80
    # horizontally at z = 95 (5 mm above the base): radius 7.5
    t, n = _one(cone, (-50, 0, 95), (1, 0, 0))
    assert t == pytest.approx(42.5)
    np.testing.assert_allclose(n, np.array([-2, 0, -1]) / np.sqrt(5), atol=1e-12)
    # down along z at x = 2: radius 2 is 16 mm above the base, z = 84
    t, n = _one(cone, (2, 0, 0), (0, 0, 1))
    assert t == pytest.approx(84)
    np.testing.assert_allclose(n, np.array([2, 0, -1]) / np.sqrt(5), atol=1e-12)
    # from below, through the base cap
    t, n = _one(cone, (3, 0, 200), (0, 0, -1))
    assert t == pytest.approx(100)
    np.testing.assert_allclose(n, [0, 0, 1], atol=1e-12)
    # the mirrored nappe beyond the apex is not part of the cone
    assert _one(cone, (-50, 0, 75), (1, 0, 0))[0] == np.inf


def test_frustum_has_a_top_cap():
    fr = Cone((0, 0, 100), (0, 0, -1), radius_mm=10, height_mm=20, top_radius_mm=5)
    t, n = _one(fr, O, (0.01, 0, 1))
    assert t == pytest.approx(80)
    np.testing.assert_allclose(n, [0, 0, -1], atol=1e-12)
    t, _ = _one(fr, (-50, 0, 90), (1, 0, 0))  # half way up: radius 7.5
    assert t == pytest.approx(42.5)


def test_ray_hits_sphere():
    sph = Sphere((0, 0, 100), 10)
    t, n = _one(sph, O, (0, 0, 1))
    assert t == pytest.approx(90)
    np.testing.assert_allclose(n, [0, 0, -1])
    t, n = _one(sph, (6, 0, 0), (0, 0, 2))  # direction length 2: t halves
    assert t == pytest.approx(46)
    np.testing.assert_allclose(n, [0.6, 0, -0.8], atol=1e-12)
    assert _one(sph, (10.01, 0, 0), (0, 0, 1))[0] == np.inf
    # from inside: the far side
    t, n = _one(sph, (0, 0, 100), (1, 0, 0))
    assert t == pytest.approx(10)
    np.testing.assert_allclose(n, [1, 0, 0])


def test_textured_plane_is_finite_and_reads_its_texture():
    tex = np.array([[0, 255, 0], [255, 0, 255]], np.uint8)  # 3 × 2 texels of 10 mm
    R = rotation_from_euler_deg(0, 30, 0)
    t0 = np.array([0.0, 0.0, 300.0])
    board = TexturedPlane(R, t0, tex, mm_per_texel=10.0, texture_origin_mm=(-15.0, -10.0), albedo=0.5)
    assert board.size_mm == (30.0, 20.0)
    # texel (c, r) centre in the board frame: x = −15 + 10c + 5, y = −10 + 10r + 5
    for c in range(3):
        for r in range(2):
            p_board = np.array([-10.0 + 10 * c, -5.0 + 10 * r, 0.0])
            p = R @ p_board + t0
            t, n = _one(board, O, p)
            assert t == pytest.approx(1.0)
            np.testing.assert_allclose(n, R[:, 2], atol=1e-12)
            assert board.albedo_at(p[None])[0] == pytest.approx(0.5 * tex[r, c] / 255, abs=1e-6)
    # bilinear half way between texels (0, 0) = 0 and (1, 0) = 255
    p = R @ np.array([-5.0, -5.0, 0.0]) + t0
    assert board.albedo_at(p[None])[0] == pytest.approx(0.25, abs=1e-6)
    # just outside the print: miss
    p = R @ np.array([15.2, 0.0, 0.0]) + t0
    assert _one(board, O, p)[0] == np.inf


def test_nearest_hit_is_the_occluder_and_normals_face_the_ray():
    scene = Scene(objects=[Plane((0, 0, 100), (0, 0, 1)), Sphere((0, 0, 80), 5)])  # plane normal points away
    d = np.array([[0, 0, 1.0], [0.2, 0, 1.0]])
    t, n, oid = intersect_scene(scene, np.zeros(3), d)
    assert oid.tolist() == [1, 0]
    np.testing.assert_allclose(t, [75, 100])
    np.testing.assert_allclose(n, [[0, 0, -1], [0, 0, -1]], atol=1e-12)  # plane normal flipped to the viewer
    t, n, oid = intersect_scene(scene, np.zeros(3), np.array([[0, 0, -1.0]]))
    assert oid[0] == -1 and t[0] == np.inf and np.isnan(n[0]).all()


def test_shadow_segments():
    scene = Scene(objects=[Plane((0, 0, 100), (0, 0, -1)), Sphere((0, 0, 50), 10), Box((30, 0, 90), (10, 10, 20))])
    p = np.array([[0, 0, 100.0], [5, 0, 100.0], [50, 0, 100.0], [0, 30, 100.0], [30, 0, 80.0]])
    oid = np.array([0, 0, 0, 0, 2])
    blocked = segment_blocked(scene, p, np.zeros(3), skip_id=oid)
    # (0,0,100) and (5,0,100) lie behind the sphere as seen from the origin; (50,0,100) and (0,30,100) do not;
    # the box's own front face is not shadowed by the box itself.
    assert blocked.tolist() == [True, True, False, False, False]
    # the sphere's shadow on the plane is the disc of radius 100·tan(asin(10/50)) around the axis
    r_shadow = 100 * np.tan(np.arcsin(10 / 50))
    x = np.array([r_shadow - 0.05, r_shadow + 0.05])
    pts = np.column_stack([np.zeros(2), x, np.full(2, 100.0)])
    assert segment_blocked(scene, pts, np.zeros(3), skip_id=np.zeros(2, int)).tolist() == [True, False]


def test_invalid_primitives_are_rejected_with_a_message():
    with pytest.raises(ValueError, match="albedo"):
        Sphere((0, 0, 1), 1, albedo=1.5)
    with pytest.raises(ValueError, match="rotation"):
        Box((0, 0, 0), (1, 1, 1), np.diag([1, 1, -1]))
    with pytest.raises(ValueError, match="non-zero"):
        Plane((0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="not a primitive"):
        Scene(objects=[object()])


def test_textured_plane_lookup_handles_many_points():
    # cv2.remap refuses maps with 32767 rows or more: 100 000 lookups must still work.
    tex = np.tile(np.arange(256, dtype=np.uint8), (4, 1))
    board = TexturedPlane(np.eye(3), np.zeros(3), tex, mm_per_texel=1.0)
    x = np.linspace(0.5, 255.5, 100_000)
    p = np.column_stack([x, np.full_like(x, 2.0), np.zeros_like(x)])
    np.testing.assert_allclose(board.albedo_at(p), (x - 0.5) / 255, atol=1e-5)
