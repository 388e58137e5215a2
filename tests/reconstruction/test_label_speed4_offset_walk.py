"""`_label_kernels.offset_depth_walk` (decision 0078) against the chunked NumPy walk it replaces in
labelling._choose_offset (offset_points four offsets at a time, geometry.depth_cam, the inside share)."""

from __future__ import annotations

import numpy as np

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction import _label_kernels as K
from reconstruction.geometry import depth_cam
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import rig_model


def _old_walk(model, rel, off, top, xy_cam, z_min, z_max, frac):
    """The walk as labelling._choose_offset did it before decision 0078."""
    m = len(rel)
    passing = []
    n_fail = 0
    for k0 in range(0, len(top), 4):
        k1 = min(k0 + 4, len(top))
        p, in_pat = K.offset_points(rel, off, top, k0, k1, xy_cam, model.xy_junction, int(model.index_min),
                                    int(model.index_max), model.procam.R_proj_cam, model.procam.t_proj_cam)
        z = depth_cam(model.procam, p).reshape(k1 - k0, m)
        inside_c = (z >= z_min) & (z <= z_max) & in_pat
        ok_c = np.count_nonzero(inside_c, axis=1) / inside_c.shape[1] >= frac
        for k in range(k1 - k0):
            if ok_c[k]:
                passing.append((k0 + k, inside_c[k]))
            elif not passing:
                n_fail += 1
        if len(passing) >= 2:
            passing = passing[:2]
            break
    return passing, n_fail


def test_offset_depth_walk_equals_the_chunked_numpy_walk():
    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.zeros(5))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.zeros(5))
    t = np.array([180.0, 60.0, 40.0])
    model = rig_model(ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t), GridPattern(), (500.0, 1200.0))
    rng = np.random.default_rng(21)
    outcomes = set()
    for trial in range(300):
        m = int(rng.integers(1, 60))
        # a plane at a random depth seen by the camera: the true offset puts it there, others elsewhere
        rel = rng.integers(-5, 6, (m, 2)).astype(np.int64)
        n_off = int(rng.integers(1, 17))
        off = rng.integers(-6, 7, (n_off + 3, 2)).astype(np.int64)
        top = rng.permutation(n_off + 3)[:n_off].astype(np.intp)
        xy_cam = rng.normal(0, 0.15, (m, 2))
        z_min, z_max = sorted(rng.uniform(300, 1500, 2))
        frac = float(rng.choice([0.5, 0.9, 1.0]))
        pass_k, n_fail, inside = K.offset_depth_walk(rel, off, top, xy_cam, model.xy_junction, int(model.index_min),
                                                     int(model.index_max), model.procam.R_proj_cam, model.procam.t_proj_cam,
                                                     float(z_min), float(z_max), frac)
        passing, n_fail_ref = _old_walk(model, rel, off, top, xy_cam, z_min, z_max, frac)
        assert n_fail == n_fail_ref
        assert [int(k) for k in pass_k if k >= 0] == [k for k, _ in passing]
        if passing:
            np.testing.assert_array_equal(inside, passing[0][1])
        outcomes.add(len(passing))
    assert outcomes == {0, 1, 2}  # every branch was exercised


def test_offset_depth_walk_depth_equals_depth_cam():
    # the walk's z is R[:, 2]·(p − t) in scalar code; NumPy's matmul in depth_cam goes through BLAS and can
    # differ in the last bits (decision 0078), so the limits are put 1e-12 relative inside and outside z
    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.zeros(5))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.zeros(5))
    t = np.array([180.0, 60.0, 40.0])
    model = rig_model(ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t), GridPattern(), (500.0, 1200.0))
    rng = np.random.default_rng(22)
    for _ in range(200):
        rel = np.zeros((1, 2), np.int64)
        off = rng.integers(-10, 11, (1, 2)).astype(np.int64)
        xy_cam = rng.normal(0, 0.15, (1, 2))
        p, _ = K.offset_points(rel, off, np.zeros(1, np.intp), 0, 1, xy_cam, model.xy_junction, int(model.index_min),
                               int(model.index_max), model.procam.R_proj_cam, model.procam.t_proj_cam)
        z = float(depth_cam(model.procam, p)[0])
        e = 1e-12 * abs(z)
        args = (rel, off, np.zeros(1, np.intp), xy_cam, model.xy_junction, int(model.index_min), int(model.index_max),
                model.procam.R_proj_cam, model.procam.t_proj_cam)
        assert K.offset_depth_walk(*args, z - e, z + e, 1.0)[0][0] == 0
        assert K.offset_depth_walk(*args, z + e, np.inf, 1.0)[0][0] == -1
        assert K.offset_depth_walk(*args, -np.inf, z - e, 1.0)[0][0] == -1
