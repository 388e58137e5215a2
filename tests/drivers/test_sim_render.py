"""Rendering against analytic answers: projection round trips with distortion, the Lambertian formula,
truth consistency, grid lines landing where the pattern says, unbiased anti-aliasing, shadows, noise."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from drivers.sim import (
    Plane,
    RenderOptions,
    Scene,
    Sphere,
    TexturedPlane,
    render,
    preset,
)
from drivers.sim.presets import tabletop_procam
from drivers.sim.render import project_to_projector
from reconstruction.patterns import GridPattern


def small_rig(*, cam_dist=(-0.1, 0.05, 0.001, -0.001, 0.0), proj_dist=(0.05, 0.0, 0.0, 0.0, 0.0)) -> ProCam:
    camera = Intrinsics(160, 120, np.array([[220.0, 0, 81.3], [0, 221.0, 58.6], [0, 0, 1]]), np.array(cam_dist))
    projector = Intrinsics(200, 200, np.array([[300.0, 0, 99.5], [0, 300.0, 101.0], [0, 0, 1]]), np.array(proj_dist))
    t = np.array([120.0, -10.0, 5.0])
    return ProCam(camera, projector, look_at(t, np.array([0.0, 0.0, 500.0])), t)


TILTED = Scene(objects=[Plane((0, 0, 500), (0.2, -0.3, -1.0), albedo=0.6)])
NO_NOISE = RenderOptions(noise_grey=0.0, supersample=1, bit_depth=16, ambient=0.1, projector_gain=0.8)


def test_projection_round_trips_with_distortion():
    rng = np.random.default_rng(1)
    for dev in (tabletop_procam().camera, tabletop_procam().projector, small_rig().camera):
        q = rng.uniform([-0.5, -0.5], [dev.width - 0.5, dev.height - 0.5], size=(500, 2))
        z = rng.uniform(100, 2000, size=500)
        p = dev.rays(q) * z[:, None]
        np.testing.assert_allclose(dev.project(p), q, atol=1e-6)


def test_projector_lookup_rejects_points_that_distortion_would_fold_into_the_image():
    proj = Intrinsics(200, 200, np.array([[300.0, 0, 99.5], [0, 300.0, 99.5], [0, 0, 1]]), np.array([-0.5, 0, 0, 0, 0]))
    far = np.array([[1400.0, 0.0, 1000.0]])  # normalised radius 1.4: 1 + k1·r² ≈ 0 folds it back near the axis
    assert np.all(np.abs(proj.project(far)[0] - 99.5) < 100)  # the raw model would put it inside the image
    assert np.isnan(project_to_projector(proj, far)).all()
    near = np.array([[10.0, -20.0, 1000.0]])
    np.testing.assert_allclose(project_to_projector(proj, near), proj.project(near))


def test_white_projector_render_of_a_plane_is_the_lambertian_formula():
    procam = small_rig()
    white = np.full((200, 200), 255, np.uint8)
    for gamma in (1.0, 2.2):
        opts = RenderOptions(noise_grey=0.0, supersample=1, bit_depth=16, ambient=0.1, projector_gain=0.8, gamma=gamma)
        img, truth = render(procam, TILTED, white, options=opts, rng=np.random.default_rng(0))
        p = truth.p_proj.astype(np.float64)
        n = truth.normal_proj.astype(np.float64)
        cos = -(n * p).sum(axis=2) / np.linalg.norm(p, axis=2)
        expected = 65535 * (0.6 * (0.1 + 0.8 * cos * truth.lit)) ** (1 / gamma)
        assert truth.lit.mean() > 0.5 and (~truth.lit).sum() > 100  # some of the plane is outside the projector
        np.testing.assert_allclose(img.astype(float), expected, atol=1.0)
        np.testing.assert_allclose(np.linalg.norm(n, axis=2), 1, atol=1e-6)


def test_truth_is_consistent_with_both_pinholes():
    procam = small_rig()
    _, truth = render(procam, TILTED, None, options=NO_NOISE, rng=np.random.default_rng(0))
    H, W = truth.depth_cam.shape
    p = truth.p_proj.reshape(-1, 3).astype(np.float64)
    # the camera sees p at its own pixel centre, at depth depth_cam
    p_cam = procam.proj_to_cam(p)
    np.testing.assert_allclose(p_cam[:, 2], truth.depth_cam.ravel(), rtol=1e-6)
    np.testing.assert_allclose(procam.camera.project(p_cam), procam.camera.pixel_grid(), atol=2e-3)
    # q_proj re-projects: the projector maps p to q_proj, and the projector ray through q_proj passes p
    q = truth.q_proj.reshape(-1, 2).astype(np.float64)
    ok = np.isfinite(q[:, 0])
    assert ok.mean() > 0.5
    np.testing.assert_allclose(q[ok], procam.projector.project(p[ok]), atol=2e-3)
    ray = procam.projector.rays(q[ok])
    np.testing.assert_allclose(ray * p[ok, 2:3], p[ok], atol=0.01)
    # on a plane every point lies on it
    plane = TILTED.objects[0]
    np.testing.assert_allclose((p - plane.point_mm) @ plane.normal, 0, atol=1e-3)
    assert (truth.object_id == 0).all()
    assert truth.lit[ok.reshape(H, W)].all() and not truth.lit[~ok.reshape(H, W)].any()


def test_projected_grid_lands_on_its_lines():
    procam = small_rig(proj_dist=(0, 0, 0, 0, 0))
    pattern = GridPattern(pitch_px=12.0, lines=15, line_width_px=3.0, centre_px=(99.5, 101.0))
    image = pattern.render(200, 200)
    opts = RenderOptions(noise_grey=0.0, supersample=3, ambient=0.0, projector_gain=1.0)
    img, truth = render(procam, TILTED, image, options=opts, rng=np.random.default_rng(0))
    q = truth.q_proj.reshape(-1, 2).astype(np.float64) - np.array(pattern.centre_px)
    d = np.full(len(q), np.inf)
    for family, n in ((1, pattern.n1), (2, pattern.n2)):
        s = (q[:, 1] - n * q[:, 0]) / np.hypot(n, 1)
        c = pattern.offsets_px(family) / np.hypot(n, 1)
        d = np.minimum(d, np.abs(s[:, None] - c[None, :]).min(axis=1))
    d = d.reshape(img.shape)
    bright = truth.lit & (img > 100)  # a lit albedo-0.6 line peaks near 150
    assert bright.sum() > 200
    # lines are 3 px wide and a camera pixel spans ~1.4 projector pixels here
    assert np.nanmax(d[bright]) < 1.5 + 1.0
    far = truth.lit & (d > 4.5)
    assert far.sum() > 200
    assert img[far].max() <= 2  # between the lines: dark (no ambient, no noise)


def _box_line(width: int, centre: float, half_width: float) -> np.ndarray:
    """A vertical projector line: exact box integral over each pixel column."""
    u = np.arange(width)
    lo, hi = centre - half_width, centre + half_width
    cover = np.clip(np.minimum(u + 0.5, hi) - np.maximum(u - 0.5, lo), 0, 1)
    return np.tile((cover * 255).round().astype(np.uint8), (40, 1))


def test_supersampling_is_symmetric_about_pixel_centres():
    # Camera = projector (same pinhole, same place): camera pixel q sees projector pixel q, so the centroid
    # of a rendered line must equal the projector line's centre; a half-pixel-biased sampler shifts it.
    K = np.array([[100.0, 0, 39.5], [0, 100.0, 19.5], [0, 0, 1]])
    dev = Intrinsics(80, 40, K)
    procam = ProCam(dev, dev, np.eye(3), np.zeros(3))
    scene = Scene(objects=[Plane((0, 0, 300), (0, 0, -1), albedo=1.0)])
    for s in (2, 3, 4):
        opts = RenderOptions(noise_grey=0.0, supersample=s, ambient=0.0, projector_gain=1.0, bit_depth=16)
        for centre in (30.0, 41.3, 52.75):
            img, _ = render(procam, scene, _box_line(80, centre, 1.5), options=opts, rng=np.random.default_rng(0))
            row = img[20].astype(float)
            u = np.arange(80)
            centroid = (row * u).sum() / row.sum()
            assert centroid == pytest.approx(centre, abs=0.01), (s, centre)


def test_sphere_casts_the_analytic_shadow_on_the_table():
    # Projector and camera nearly together above a plane, a sphere between them and the plane.
    dev = Intrinsics(120, 120, np.array([[150.0, 0, 59.5], [0, 150.0, 59.5], [0, 0, 1]]))
    procam = ProCam(dev, dev, look_at(np.array([60.0, 0, 0]), np.array([0, 0, 400.0])), np.array([60.0, 0, 0]))
    scene = Scene(objects=[Plane((0, 0, 400), (0, 0, -1)), Sphere((0, 0, 200), 30)])
    opts = RenderOptions(noise_grey=0.0, supersample=1, ambient=0.1, projector_gain=0.8)
    img, truth = render(procam, scene, np.full((120, 120), 255, np.uint8), options=opts, rng=np.random.default_rng(0))
    on_plane = truth.object_id == 0
    p = truth.p_proj.astype(np.float64)
    r_shadow = 400 * np.tan(np.arcsin(30 / 200))
    radial = np.hypot(p[..., 0], p[..., 1])
    inside = on_plane & (radial < r_shadow - 1)
    outside = on_plane & (radial > r_shadow + 1) & np.isfinite(truth.q_proj[..., 0])
    assert inside.sum() > 20 and outside.sum() > 100
    assert not truth.lit[inside].any() and truth.lit[outside].all()
    assert np.all(img[inside] == round(255 * 0.8 * 0.1))  # ambient only
    assert np.all(img[outside] > 150)
    # the camera cannot see the plane behind the sphere: those pixels belong to the sphere
    centre_px = procam.camera.project(procam.proj_to_cam(np.array([[0, 0, 200.0]])))[0]
    assert truth.object_id[int(round(centre_px[1])), int(round(centre_px[0]))] == 1


def test_noise_has_the_requested_standard_deviation_and_is_seeded():
    procam = small_rig()
    opts = RenderOptions(noise_grey=2.0, supersample=1, ambient=0.3, projector_gain=0.0)
    a, _ = render(procam, TILTED, None, options=opts, rng=np.random.default_rng(5))
    b, _ = render(procam, TILTED, None, options=opts, rng=np.random.default_rng(5))
    c, _ = render(procam, TILTED, None, options=opts, rng=np.random.default_rng(6))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    resid = a.astype(float) - 255 * 0.6 * 0.3
    assert resid.std() == pytest.approx(np.sqrt(4 + 1 / 12), rel=0.06)
    assert abs(resid.mean()) < 0.1


def test_textured_plane_alone_renders_its_texture_under_white_light():
    # A 4 × 4 checkerboard of 20 mm texels facing the projector = camera, 400 mm away: 10 px per texel,
    # texel (c, r) centred on camera pixel (35 + 10c, 35 + 10r).
    tex = (np.indices((4, 4)).sum(axis=0) % 2 * 255).astype(np.uint8)
    board = TexturedPlane(np.eye(3), np.array([0.0, 0.0, 400.0]), tex, mm_per_texel=20.0, texture_origin_mm=(-40.0, -40.0), albedo=0.9)
    dev = Intrinsics(100, 100, np.array([[200.0, 0, 50.0], [0, 200.0, 50.0], [0, 0, 1]]))
    procam = ProCam(dev, dev, np.eye(3), np.zeros(3))
    opts = RenderOptions(noise_grey=0.0, supersample=1, ambient=0.0, projector_gain=1.0)
    img, truth = render(procam, Scene(objects=[board]), np.full((100, 100), 255, np.uint8), options=opts, rng=np.random.default_rng(0))
    for r in range(4):
        for c in range(4):
            v, u = 35 + 10 * r, 35 + 10 * c
            p = truth.p_proj[v, u].astype(np.float64)
            cos = p[2] / np.linalg.norm(p)  # the board faces the projector = camera at the origin
            assert abs(int(img[v, u]) - 0.9 * tex[r, c] * cos) <= 0.5
    # outside the print (±40 mm = ±20 px): nothing
    assert truth.object_id[50, 50] == 0 and truth.object_id[50, 50 + 21] == -1 and truth.object_id[50, 50 - 21] == -1
    assert img[50, 75] == 0 and img[5, 5] == 0
    assert np.isnan(truth.depth_cam[5, 5]) and truth.depth_cam[50, 50] == pytest.approx(400)


def test_render_rejects_a_projector_image_of_the_wrong_size():
    with pytest.raises(ValueError, match="projector's resolution"):
        render(small_rig(), TILTED, np.zeros((10, 10), np.uint8), options=NO_NOISE, rng=np.random.default_rng(0))


def test_tabletop_preset_grid_is_mostly_on_the_scene_and_visible():
    rig = preset("tabletop")
    pc = rig.procam
    pattern = GridPattern()
    ii, jj = np.meshgrid(pattern.indices, pattern.indices, indexing="ij")
    q = pattern.junction_uv(ii.ravel(), jj.ravel())
    from drivers.sim import intersect_scene, segment_blocked

    d = pc.projector.rays(q)
    t, n, oid = intersect_scene(rig.scene, np.zeros(3), d)
    assert (oid >= 0).all()
    p = d * t[:, None]
    q_cam = pc.camera.project(pc.proj_to_cam(p))
    in_image = (q_cam[:, 0] > 0) & (q_cam[:, 0] < pc.camera.width - 1) & (q_cam[:, 1] > 0) & (q_cam[:, 1] < pc.camera.height - 1)
    faces_cam = ((pc.t_proj_cam - p) * n).sum(axis=1) > 0
    occluded = segment_blocked(rig.scene, p, pc.t_proj_cam, skip_id=oid)
    visible = in_image & faces_cam & ~occluded
    assert visible.mean() > 0.8
    z = pc.proj_to_cam(p[visible])[:, 2]
    assert rig.depth_range_mm[0] <= z.min() and z.max() <= rig.depth_range_mm[1]


def test_adaptive_supersampling_matches_casting_every_subsample():
    # Smooth pixels are filled by a first-order expansion, edges by real rays: compare with all rays.
    from drivers.sim import Box
    from drivers.sim.render import Geometry

    procam = small_rig()
    scene = Scene(objects=[Plane((0, 0, 520), (0, -0.2, -1)), Sphere((0, 0, 470), 30, albedo=0.9), Box((-40, 30, 490), (30, 30, 40))])
    image = GridPattern(pitch_px=10.0, lines=19, line_width_px=2.0, centre_px=(99.5, 99.5)).render(200, 200)
    adaptive = Geometry(procam, scene, supersample=3)
    exact = Geometry(procam, scene, supersample=3, adaptive=False)
    assert 0.05 < adaptive.exact_fraction < 0.6 and exact.exact_fraction == 1.0
    a = adaptive.radiance(image, ambient=0.05, projector_gain=0.9) * 255
    e = exact.radiance(image, ambient=0.05, projector_gain=0.9) * 255
    assert np.abs(a - e).max() < 1.0  # grey levels (8-bit scale)
    assert np.abs(a - e).mean() < 0.01


def test_textured_board_in_front_of_the_table_occludes_and_shadows_it():
    tex = np.full((40, 60), 200, np.uint8)  # a 60 × 40 mm grey card, 1 mm texels
    R = look_at(np.zeros(3), np.array([0.0, 0.2, 1.0]))  # tilted slightly, facing the projector
    board = TexturedPlane(R, np.array([0.0, 0.0, 300.0]), tex, mm_per_texel=1.0, texture_origin_mm=(-30.0, -20.0))
    scene = Scene(objects=[Plane((0, 0, 500), (0, 0, -1)), board])
    procam = small_rig()
    opts = RenderOptions(noise_grey=0.0, supersample=3, ambient=0.0, projector_gain=1.0)
    img, truth = render(procam, scene, np.full((200, 200), 255, np.uint8), options=opts, rng=np.random.default_rng(0))
    on_board = truth.object_id == 1
    on_table = truth.object_id == 0
    assert on_board.sum() > 300 and on_table.sum() > 3000
    assert truth.lit[on_board].all()
    np.testing.assert_allclose(truth.depth_cam[on_board], procam.proj_to_cam(truth.p_proj[on_board])[:, 2], rtol=1e-5)
    # table points whose ray to the projector crosses the card (|x|, |y| within the card at z≈300) are dark
    p = truth.p_proj.astype(np.float64)
    from scipy.ndimage import binary_erosion

    clear_table = binary_erosion(on_table, np.ones((3, 3), bool))  # no card edge inside the pixel
    behind = clear_table & (np.abs(p[..., 0] * 300 / p[..., 2]) < 25) & (np.abs(p[..., 1] * 300 / p[..., 2]) < 15)
    assert behind.sum() > 100 and not truth.lit[behind].any() and img[behind].max() == 0
