"""The epipolar order of the two families at a crossing (decision 0083, reconstruction/acute_crossings.py):
at every lit, visible surface point the cyclic order of (epipolar direction, i-line, j-line) in the camera is
the rig's, whatever the surface's depth and normal. Simulator truth: the small rig's tilted plane and sphere,
and a plane the projector lights at grazing incidence (acute crossings, both lines near the epipolar
direction). Plus the algebra behind it: an affine map keeps the cyclic order of three lines when det > 0."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks._common import sample_bilinear
from benchmarks.bench_extraction import truth_grid
from reconstruction.acute_crossings import epipolar_dir_cam, expected_order_sign, order_sign
from reconstruction.rigmodel import rig_model


def _true_crossings(s):
    """Visible true junctions: positions (N, 2), the true i- and j-line image directions (N, 2) each, and
    the crossing angle in degrees (from the truth's projector map)."""
    tg = truth_grid(s.truth, s.pattern, r_vis=3.0)
    c = tg["c"]
    q = tg["q"][tg["visible"]]
    gi_v, gi_u = np.gradient(c[..., 0])
    gj_v, gj_u = np.gradient(c[..., 1])
    gi = sample_bilinear(np.stack([gi_u, gi_v], -1).astype(np.float32), q)
    gj = sample_bilinear(np.stack([gj_u, gj_v], -1).astype(np.float32), q)
    ok = np.isfinite(gi).all(axis=1) & np.isfinite(gj).all(axis=1)
    q, gi, gj = q[ok], gi[ok], gj[ok]
    t_i = np.column_stack([-gi[:, 1], gi[:, 0]])  # a line of constant index runs across its gradient
    t_j = np.column_stack([-gj[:, 1], gj[:, 0]])
    cos = np.abs((gi * gj).sum(axis=1)) / np.linalg.norm(gi, axis=1) / np.linalg.norm(gj, axis=1)
    return q, t_i, t_j, np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


@pytest.fixture(scope="module")
def grazing_scene(small_scene):
    """The small rig shown its grid on a plane the projector lights at grazing incidence (|cos| ≈ 0.05
    between its normal and the projector's axis) and the camera sees from the front: acute crossings."""
    from drivers.sim import Plane, RenderOptions, Scene, render

    from tests.reconstruction.conftest import SmallScene

    s = small_scene
    scene = Scene(objects=[Plane(np.array([0, 0, 850.0]), np.array([1.0, 0.0, -0.05]))])
    image, truth = render(
        s.procam, scene, s.pattern.render(800, 600), options=RenderOptions(noise_grey=2.0, supersample=2), rng=np.random.default_rng(0)
    )
    return SmallScene(s.procam, s.pattern, image, truth, s.depth_range_mm)


@pytest.mark.parametrize("which", ["small_scene", "grazing_scene"])
def test_true_crossings_show_the_rigs_order_and_swapped_families_the_other(which, request):
    s = request.getfixturevalue(which)
    model = rig_model(s.procam, s.pattern, s.depth_range_mm)
    q, t_i, t_j, angle = _true_crossings(s)
    e = epipolar_dir_cam(model, q)
    expected = expected_order_sign(model, q)
    assert len(q) >= 100, len(q)
    assert (expected != 0).all()
    right = order_sign(e, t_i, t_j) == expected
    swapped = order_sign(e, t_j, t_i) == expected
    # every true crossing in the rig's order; with the families swapped, none (a wrong assignment is seen)
    assert right.all(), (int((~right).sum()), q[~right][:5])
    assert not swapped.any()
    if which == "grazing_scene":
        # the grazing plane's crossings are acute: the case where the predicted directions fail
        assert np.median(angle) < 30.0, np.median(angle)


def test_order_is_kept_by_affine_maps_with_positive_determinant():
    rng = np.random.default_rng(7)
    n = 2000
    ang = rng.uniform(0, np.pi, (n, 3))
    e, a, b = (np.column_stack([np.cos(ang[:, k]), np.sin(ang[:, k])]) for k in range(3))
    A = rng.normal(size=(n, 2, 2))
    det = np.linalg.det(A)
    keep = np.abs(det) > 0.05  # away from degenerate maps (the order of nearly parallel images is numerical)
    s0 = order_sign(e, a, b)
    s1 = order_sign(*(np.einsum("nij,nj->ni", A, x) for x in (e, a, b)))
    assert (s1[keep] == np.where(det[keep] > 0, s0[keep], -s0[keep])).all()
    # and the order is a property of the three lines, not of the vectors' signs
    assert (order_sign(-e, a, -b) == s0).all()
