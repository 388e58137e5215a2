"""Grid extraction against analytic and simulated truth: line centres, junction positions and recall,
edges (and none across a depth edge), robustness to an albedo gradient and ambient light."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.extraction import extract_grid
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import rig_model


def _sample(a: np.ndarray, q: np.ndarray) -> np.ndarray:
    m = q.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(a.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan).reshape(len(q), -1)


# --- analytic: the camera sees the projector image itself ---------------------------------------------------


def _analytic(albedo_gradient: bool):
    K = np.array([[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]])
    dev = Intrinsics(640, 480, K)
    procam = ProCam(dev, dev, np.eye(3), np.array([1.0, 0.5, 0.0]))
    pattern = GridPattern(alpha1_deg=25.0, alpha2_deg=110.0, pitch_px=26.0, lines=17, line_width_px=3.0, centre_px=(320.3, 240.7))
    img = pattern.render(640, 480).astype(np.float32) / 255
    if albedo_gradient:
        u = np.arange(640, dtype=np.float32)[None, :]
        v = np.arange(480, dtype=np.float32)[:, None]
        albedo = 0.25 + 0.75 * u / 639  # 4:1 across the image
        ambient = 15 + 50 * v / 479  # 15 … 65 grey levels of ambient light, top to bottom
        img = img * 200 * albedo + ambient
    else:
        img = img * 200 + 10
    img += np.random.default_rng(0).normal(0, 2.0, img.shape).astype(np.float32)
    return procam, pattern, np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("albedo_gradient", [False, True])
def test_line_centres_and_junctions_on_an_analytic_grid(albedo_gradient):
    procam, pattern, img = _analytic(albedo_gradient)
    model = rig_model(procam, pattern, (900.0, 1100.0))
    obs = extract_grid(img, model)
    x = obs.q[:, 0] - pattern.centre_px[0]
    y = obs.q[:, 1] - pattern.centre_px[1]
    for fam, n in ((1, pattern.n1), (2, pattern.n2)):
        sel = obs.family == fam
        c = y[sel] - n * x[sel]
        d = np.abs(c - np.rint(c / pattern.pitch_px) * pattern.pitch_px) / np.hypot(1, n)
        assert sel.sum() > 1500
        far = obs.segment[sel] >= 0  # away from crossings and line ends
        assert np.median(d[far]) < 0.05 and np.percentile(d[far], 95) < 0.12, (fam, np.median(d[far]), np.percentile(d[far], 95))
    # junctions: every interior crossing inside the image, each at the analytic position
    idx = pattern.indices[1:-1]
    ii, jj = np.meshgrid(idx, idx, indexing="ij")
    true_j = pattern.junction_uv(ii.ravel(), jj.ravel())
    inside = (true_j[:, 0] > 8) & (true_j[:, 0] < 631) & (true_j[:, 1] > 8) & (true_j[:, 1] < 471)
    true_j = true_j[inside]
    d = np.linalg.norm(obs.q_junction[:, None] - true_j[None], axis=2)
    found = d.min(axis=0) <= 0.5
    assert found.mean() >= 0.97, found.mean()
    err = d.min(axis=1)
    assert np.median(err) < 0.03 and err.max() < 0.3, (np.median(err), err.max())
    # the graph: every edge joins neighbours, with the right index step
    lab = np.stack([ii.ravel()[inside], jj.ravel()[inside]], axis=1)[np.argmin(d, axis=1)]
    steps = lab[obs.edges[:, 1]] - lab[obs.edges[:, 0]]
    np.testing.assert_array_equal(steps, obs.edge_delta)
    assert len(obs.edges) >= 0.9 * 2 * found.sum()


# --- simulated: a plane with a box standing in front of it (a depth edge all round the box) ----------------


@pytest.fixture(scope="module")
def box_scene():
    from drivers.sim import Box, Plane, RenderOptions, Scene, render

    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.array([-0.05, 0.02, 0, 0, 0]))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.array([0.03, 0, 0, 0, 0]))
    t = np.array([180.0, 60.0, 40.0])
    procam = ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t)
    scene = Scene(objects=[Plane(np.array([0, 0, 900.0]), np.array([0.1, -0.2, -1.0])), Box((-20.0, 10.0, 760.0), (140.0, 120.0, 80.0), np.eye(3))])
    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), line_width_px=3.0)
    img, truth = render(procam, scene, pattern.render(800, 600), options=RenderOptions(noise_grey=2.0, supersample=2), rng=np.random.default_rng(1))
    model = rig_model(procam, pattern, (500.0, 1200.0))
    return procam, pattern, img, truth, model


def _truth_junctions(truth, pattern, r_vis: float):
    """Sub-pixel camera position and label of every pattern junction the camera sees, and whether it is
    visible (interior junction, disk of r_vis lit and without a depth jump); plus that smoothness mask."""
    q = truth.q_proj.astype(np.float64)
    x = q[..., 0] - pattern.centre_px[0]
    y = q[..., 1] - pattern.centre_px[1]
    c = np.stack([(y - pattern.n1 * x) / pattern.pitch_px, (y - pattern.n2 * x) / pattern.pitch_px], -1)
    z = np.nan_to_num(truth.depth_cam).astype(np.float32)
    k3 = np.ones((3, 3), np.uint8)
    cont = np.isfinite(truth.depth_cam) & ((cv2.dilate(z, k3) - cv2.erode(z, k3)) <= 0.02 * np.maximum(z, 1))
    cont = cv2.erode(cont.astype(np.uint8), k3).astype(bool)
    smooth = cont & truth.lit
    k = np.rint(c)
    J = np.stack([np.stack(np.gradient(c[..., f])[::-1], -1) for f in (0, 1)], -2)  # d c_f / d(u, v)
    cand = smooth & (np.abs(c - k) < 0.5).all(-1) & np.isfinite(J).all((-1, -2))
    v, u = np.nonzero(cand)
    step = -np.einsum("nij,nj->ni", np.linalg.inv(J[v, u]), (c - k)[v, u])
    ok = (np.abs(step) <= 0.5).all(axis=1)
    qj = np.column_stack([u, v])[ok] + step[ok]
    lab = k[v[ok], u[ok]].astype(np.int64)
    lo, hi = pattern.indices[0], pattern.indices[-1]
    interior = ((lab > lo) & (lab < hi)).all(axis=1)
    clear = cv2.distanceTransform(smooth.astype(np.uint8), cv2.DIST_L2, 5)
    visible = interior & (_sample(clear, qj)[:, 0] > r_vis)
    return qj, lab, visible, cont


def test_junctions_and_edges_match_the_simulated_truth_and_no_edge_crosses_the_depth_edge(box_scene):
    procam, pattern, img, truth, model = box_scene
    obs = extract_grid(img, model)
    qt, lab, visible, cont = _truth_junctions(truth, pattern, r_vis=0.3 * model.junction_step_cam_px)
    assert visible.sum() > 200
    d = np.linalg.norm(obs.q_junction[:, None] - qt[None], axis=2)
    near = np.argmin(d, axis=1)
    err = d[np.arange(len(near)), near]
    matched = err <= 1.5
    # recall of visible junctions, precision, sub-pixel position
    recall = (d[:, visible].min(axis=0) <= 1.5).mean()
    assert recall >= 0.85, recall
    assert matched.mean() >= 0.99, matched.mean()
    assert np.median(err[matched]) < 0.06 and np.percentile(err[matched], 95) < 0.25, (np.median(err[matched]), np.percentile(err[matched], 95))
    # edges: both ends real junctions, the right index step, and a chord without a depth jump. A
    # line jumping sideways at a depth edge by under a pixel can still pass for a crossing (the known
    # failure, see docs/decisions/0056): allow 1 % of the edges to be wrong, not more.
    a, b = obs.edges[:, 0], obs.edges[:, 1]
    right = matched[a] & matched[b] & ((lab[near[b]] - lab[near[a]]) == obs.edge_delta).all(axis=1)
    t = np.linspace(0, 1, 31)
    chords = qt[near[a]][:, None] + t[None, :, None] * (qt[near[b]] - qt[near[a]])[:, None]
    on_surface = (_sample(cont.astype(np.float32), chords.reshape(-1, 2))[:, 0].reshape(len(a), -1) > 0.99).all(axis=1)
    wrong = ~(right & on_surface)
    assert wrong.sum() <= 0.01 * len(a), f"{wrong.sum()} of {len(a)} edges wrong or across a depth edge"
    # ... and both surfaces carry junctions and edges (the box is not simply lost)
    obj = truth.object_id[np.rint(obs.q_junction[:, 1]).astype(int), np.rint(obs.q_junction[:, 0]).astype(int)]
    assert (obj == 0).sum() >= 30 and (obj == 1).sum() >= 30, np.bincount(obj[obj >= 0])
    on_box = (obj[a] == 1) & (obj[b] == 1)
    assert on_box.sum() >= 30 and (~on_box).sum() >= 30
    # edges: most visible neighbour pairs are found
    assert len(obs.edges) >= 0.8 * 2 * recall * visible.sum() * 0.9
