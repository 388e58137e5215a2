"""Decision 0161: `label_epipolar`'s per-component work loop in one compiled call (`_epipolar_loop.work_loop`,
`LabelOptions.compiled_loop`, default on) gives the Python loop's outputs bit for bit: labels, residuals, components,
the ambiguous components' best-offset labels (decisions 0141, 0147) and every stats count, on graphs made to take each
of the loop's branches (splits at outliers, ambiguous components and the inlier retry, re-stepped and cut edges,
decision 0122's noise split, residual clusters, lone junctions, decision 0146's re-step of accepted components), and
on the label_epipolar calls of a simulated frame. The observation's edge steps are not changed.
"""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from reconstruction import labelling
from reconstruction.extraction import GridObservation
from reconstruction.labelling import LabelOptions, label_epipolar
from reconstruction.rigmodel import rig_model
from tests.reconstruction._truth import lattice_edges

_spec = importlib.util.spec_from_file_location("_misfit_helpers_0161", Path(__file__).with_name("test_recon_misfit_edges.py"))
_m = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_m)

VARIANTS = [{}, dict(skip_edges_accepted=True), dict(cut_misfit_edges=False), dict(residual_clusters=False), dict(neighbour_noise=False),
            dict(max_split_rounds=1), dict(min_component=3), dict(frame_retry_limit=False), dict(skip_edges_accepted=True, min_split_component=2)]
BRANCHES = ("components_split", "ambiguous", "edges_restepped", "edges_cut", "components_restepped", "ambiguity_noise_split",
            "junctions_residual_clusters", "components_restepped_accepted")


def _obs(q, edges, delta, rms=None):
    M = len(q)
    obs = GridObservation(
        q=np.zeros((0, 2)), family=np.zeros(0, np.int8), segment=np.zeros(0, np.int64), junction=np.zeros(0, np.int64),
        strength=np.zeros(0), q_junction=q, junction_dir=np.zeros((M, 2, 2)), segment_family=np.zeros(0, np.int8),
        segment_ends=np.zeros((0, 2), np.int64), segment_rms=np.zeros(0), segment_centre=np.zeros((0, 2)),
        segment_dir=np.zeros((0, 2)), edges=np.asarray(edges, np.int64).reshape(-1, 2), edge_family=np.zeros(len(edges), np.int8),
        edge_delta=np.asarray(delta, np.int64).reshape(-1, 2), edge_segment=np.zeros(len(edges), np.int64), stats={})
    return obs if rms is None else replace(obs, junction_rms=rms)


def _random_graph(seed):
    """Junctions of a few lattice patches on seed 133's rig (`test_recon_misfit_edges`), their true edges, then damage:
    junctions moved off their lines (outliers, a displaced block: a residual cluster, patches noisier than the frame), edges that skip a crossing
    (step doubled), edges with a wrong step, edges joining two patches, lone junctions, noise of 0.03–0.3 px."""
    rng = np.random.default_rng(seed)
    procam, pattern = _m.tabletop_procam(), _m._pattern()
    boxes = []
    for _ in range(rng.integers(2, 6)):
        i0, j0 = rng.integers(-16, 12, 2)
        boxes.append((i0, i0 + rng.integers(0, 7), j0, j0 + rng.integers(0, 7)))
    inside = lambda i, j: any(a <= i <= b and c <= j <= d for a, b, c, d in boxes)
    truth, q = _m._junctions(procam, pattern, inside, noise_px=float(rng.choice([0.03, 0.1, 0.3])), seed=seed)
    part = np.array([next(n for n, (a, b, c, d) in enumerate(boxes) if a <= i <= b and c <= j <= d) for i, j in truth.tolist()])
    M = len(truth)
    keep_j = rng.random(M) > 0.1  # missed junctions: the edges past them skip a crossing
    edges, delta = lattice_edges(truth, lambda k, o: part[o] == part[k] and keep_j[k] and keep_j[o])
    edges, delta = edges.tolist(), delta.tolist()
    for _ in range(rng.integers(0, 4)):  # skipped crossings: an edge claims one step where the truth is two
        k = int(rng.integers(M))
        i, j = truth[k]
        step = [(0, 1), (1, 0)][rng.integers(2)]
        far = np.flatnonzero((truth[:, 0] == i + 2 * step[0]) & (truth[:, 1] == j + 2 * step[1]))
        if len(far):
            edges.append((k, int(far[0]))), delta.append(step)
    for _ in range(rng.integers(0, 3)):  # wrong steps and edges across patches
        a, b = (int(x) for x in rng.integers(M, size=2))
        if a != b:
            edges.append((a, b)), delta.append((int(rng.integers(-1, 2)), int(rng.integers(0, 2))))
    extra = rng.choice([0.0, 0.0, 0.3, 0.6], len(boxes))
    q = q + rng.normal(0, 1, q.shape) * extra[part, None]  # noisier patches than the frame: decision 0123's frame limit
    for k in rng.choice(M, size=int(rng.integers(0, max(2, M // 15))), replace=False):  # outliers
        q[k] += rng.normal(0, 3.0, 2)
    quiet = np.flatnonzero(extra[part] == 0)
    if rng.random() < 0.7 and len(quiet) > 20:  # a displaced block of neighbours in a quiet patch: a residual cluster
        k = int(rng.choice(quiet))
        near = np.argsort(np.linalg.norm(q - q[k], axis=1))[:5]
        q[near] += rng.normal(0, 0.6, 2)
    rms = np.abs(rng.normal(0.05, 0.05, (M, 2))) * rng.choice([1.0, 10.0], (M, 1))  # arms' fit RMS (decision 0134's floor)
    model = rig_model(procam, pattern, _m.VOLUME)
    return _obs(q, edges, delta, rms), model, procam.camera.pixels_to_normalised(q)


def _same(a, b):
    for f in ("labels", "residual", "component", "ambiguous_best", "ambiguous_labels"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y, equal_nan=True), f
    assert a.stats == b.stats


def _both(obs, model, xy, options):
    d0 = obs.edge_delta.copy()
    py = label_epipolar(obs, model, xy, options=replace(options, compiled_loop=False))
    nb = label_epipolar(obs, model, xy, options=replace(options, compiled_loop=True))
    assert np.array_equal(obs.edge_delta, d0)  # the re-step works on a copy
    _same(py, nb)
    return py


def test_random_graphs_both_loops_agree_and_take_every_branch(monkeypatch):
    hit = dict.fromkeys(BRANCHES + ("lone_rejected",), 0)
    lone = labelling._lone_arm_floor

    def _lone(*args, **kwargs):  # counts the calls where decision 0134's floor rejects a lone junction
        out = lone(*args, **kwargs)
        hit["lone_rejected"] += out is not None and bool(out.any())
        return out

    monkeypatch.setattr(labelling, "_lone_arm_floor", _lone)
    base = LabelOptions(depth_min_mm=_m.VOLUME[0], depth_max_mm=_m.VOLUME[1])
    for seed in range(40):
        obs, model, xy = _random_graph(seed)
        for v in VARIANTS:
            out = _both(obs, model, xy, replace(base, **v))
            for k in BRANCHES:
                hit[k] += out.stats.get(k, 0) > 0
    missing = [k for k, n in hit.items() if n == 0]
    assert not missing, hit


@pytest.mark.parametrize("fixture", ["small_scene", "small_scene_pitch16"])
def test_simulated_frame_both_loops_agree(fixture, request, monkeypatch):
    """The frame's two label_epipolar calls (the junctions; piece_junctions' graph), under the default options and
    decision 0146's: both loops agree, and the pipeline's output does not depend on the switch."""
    from reconstruction import pipeline
    from reconstruction.pipeline import ReconstructOptions, reconstruct

    s = request.getfixturevalue(fixture)
    calls = []

    def _capture(obs, model, xy_cam, *, options=LabelOptions()):
        calls.append((obs, model, np.array(xy_cam), options))
        return label_epipolar(obs, model, xy_cam, options=options)

    monkeypatch.setattr(labelling, "label_epipolar", _capture)
    monkeypatch.setattr(pipeline, "label_epipolar", _capture)
    o = ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])
    res = reconstruct(s.image, s.procam, s.pattern, options=o)
    assert len(calls) >= 1 and len(calls[0][0].q_junction) > 100
    for obs, model, xy, lo in calls:
        for v in ({}, dict(skip_edges_accepted=True)):
            _both(obs, model, xy, replace(lo, **v))
    off = reconstruct(s.image, s.procam, s.pattern, options=replace(o, label=replace(o.label, compiled_loop=False)))
    assert np.array_equal(res.points_proj, off.points_proj, equal_nan=True) and np.array_equal(res.junction_labels, off.junction_labels)
