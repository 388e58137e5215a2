"""Decision 0134: a lone junction (a graph component of one) judged with its arms' fit RMS as a noise floor."""
import numpy as np
from dataclasses import replace
from types import SimpleNamespace

from reconstruction.labelling import UNLABELLED, LabelOptions, _lone_arm_floor


def _groups(sizes):
    bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(np.intp)
    return np.arange(bounds[-1], dtype=np.intp), bounds


def test_lone_arm_floor_rejects_only_rough_lone_junctions():
    # groups: lone (rough arms), lone (clean arms), a pair (rough arms), lone not written
    order, bounds = _groups([1, 1, 2, 1])
    rms = np.array([[0.14, 0.16], [0.03, 0.03], [0.3, 0.3], [0.3, 0.3], [0.3, 0.3]])
    obs = SimpleNamespace(junction_rms=rms)
    written = np.array([True, True, True, False])
    s1 = np.full(4, 0.043**2)
    s2 = np.full(4, 0.58**2)  # seed 104's runner-up: 0.58 px
    n_eff = np.array([1.0, 1.0, 2.0, 1.0])
    labels = np.arange(10, dtype=np.int64).reshape(5, 2)
    residual = np.full(5, 0.043)
    out = _lone_arm_floor(obs, order, bounds, written, s1, s2, n_eff, labels, residual, LabelOptions())
    assert out is not None and out.tolist() == [True, False, False, False]
    assert (labels[0] == UNLABELLED).all() and np.isnan(residual[0])
    assert (labels[1:] == np.arange(2, 10).reshape(4, 2)).all() and np.isfinite(residual[1:]).all()
    # switched off, or a clear runner-up (1 px): nothing changes
    lab2 = np.arange(10, dtype=np.int64).reshape(5, 2)
    assert _lone_arm_floor(obs, order, bounds, written, s1, s2, n_eff, lab2, residual.copy(), LabelOptions(lone_arm_floor=False)) is None
    # a runner-up at the residual cap (1 px) is left as the compiled call judged it
    assert _lone_arm_floor(obs, order, bounds, written, s1, np.ones(4), n_eff, lab2, residual.copy(), LabelOptions()) is None
    assert _lone_arm_floor(obs, order, bounds, written, s1, np.full(4, 0.65**2), n_eff, lab2, residual.copy(), LabelOptions()) is not None
    lab2[:] = np.arange(10).reshape(5, 2)
    assert (lab2 == np.arange(10).reshape(5, 2)).all()
    # an observation without arm fits (the piece-junction graphs): no floor
    assert _lone_arm_floor(SimpleNamespace(q_junction=np.zeros((5, 2))), order, bounds, written, s1, s2, n_eff, lab2, residual.copy(),
                           LabelOptions()) is None


def test_seed_104_aliased_lone_junction_not_labelled():
    """Unseen seed 104 (decision 0132): one lone junction ~0.9 px off its true place (aliased lines beside it) was
    labelled 77 projector px wrong; against simulated truth, with the floor no labelled junction is wrong and the
    > 1 % share is within the limit; without it the wrong one is back (the test can fail)."""
    import cv2
    cv2.setNumThreads(1)
    from benchmarks._common import render_scene, sample_bilinear
    from benchmarks.unseen import draw_scene
    from drivers.sim.presets import depth_range
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    rig, procam, scene, pattern, noise = draw_scene(104)
    img, truth = render_scene(procam, scene, pattern, noise_grey=noise, seed=104)
    dr = depth_range(procam, scene)
    out = {}
    for on in (True, False):
        o = ReconstructOptions(depth_min_mm=dr[0], depth_max_mm=dr[1])
        res = reconstruct(img, procam, pattern, options=replace(o, label=replace(o.label, lone_arm_floor=on)))
        lab = res.junction_labels
        ok = lab[:, 0] != UNLABELLED
        qp = sample_bilinear(truth.q_proj, res.junctions_cam, dtype=np.float32)
        dd = np.linalg.norm(qp - pattern.junction_uv(lab[:, 0], lab[:, 1]), axis=1)
        p_true = sample_bilinear(truth.p_proj, res.q_cam, dtype=np.float32)
        good = np.isfinite(p_true).all(axis=1)
        rel = np.linalg.norm(res.points_proj[good] - p_true[good], axis=1) / np.linalg.norm(p_true[good], axis=1)
        out[on] = (int((ok & (dd > 2)).sum()), float((rel > 0.01).mean()), int(ok.sum()))
    assert out[True][0] == 0 and out[True][1] <= 0.002
    assert out[False][0] >= 1 and out[False][1] > out[True][1]
    assert out[True][2] >= out[False][2] - 3  # only the rough lone junctions go
