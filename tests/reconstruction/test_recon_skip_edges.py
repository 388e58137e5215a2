"""Decision 0125: graph edges that skip crossings extraction missed take the step the epipolar geometry names.

An edge along an i-line over j-crossings that were not found claims one j-step where the truth is k. On a well-posed
rig each j-step moves the junction's label a clear distance off its epipolar line, so the jump of the signed residual
across the edge names k (`_ambiguity_kernels.edge_steps`); an ambiguous component whose edges change is labelled again.
"""

import importlib.util
from pathlib import Path

import numpy as np

from reconstruction._ambiguity_kernels import edge_steps
from reconstruction.rigmodel import UNLABELLED

_spec = importlib.util.spec_from_file_location("_amb_helpers_skip", Path(__file__).with_name("test_recon_ambiguous_wellposed.py"))
_a = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_a)


def _line_component(r_signed: np.ndarray, step_px: float):
    """m junctions labelled (0, j) on a pattern whose j-step moves a junction step_px (projector px) across the
    epipolar lines y = const; junction k's line lies r_signed[k] px from its label. Returns lab, ln, xy_junction, fx."""
    fx = 1000.0
    L = 40
    ii, jj = np.meshgrid(np.arange(L), np.arange(L), indexing="ij")
    xy_junction = np.stack([jj * 0.02, ii * 0.02 + jj * step_px / fx], axis=-1).astype(np.float64)
    m = len(r_signed)
    lab = np.column_stack([np.zeros(m), np.arange(m)]).astype(np.int64)
    y = xy_junction[0, np.arange(m), 1]
    ln = np.column_stack([np.zeros(m), np.ones(m), -(y - r_signed / fx)])
    return lab, ln, xy_junction, fx


def test_edge_steps_names_the_skipped_count_only_when_one_step_fits():
    step = 0.6
    # junctions 0..5 on consecutive j-lines; the edge 2 → 3 really spans 3 lines (two missed), so the labels
    # after it are 2 lines short: their residuals jump by 2·step across that edge
    true_j = np.array([0, 1, 2, 5, 6, 7])
    r_true = np.array([0.02, -0.01, 0.03, 0.0, -0.02, 0.01])
    lab, ln, xy, fx = _line_component(r_true, step)
    ln = ln.copy()
    ln[:, 2] = -(xy[0, true_j, 1] - r_true / fx)  # each junction's line through its true label
    pa = np.arange(5, dtype=np.intp)
    pb = pa + 1
    d_i = np.zeros(5, np.int64)
    d_j = np.ones(5, np.int64)
    k = edge_steps(pa, pb, d_i, d_j, lab, ln, xy, 0, 39, fx, 6, 0.15)
    assert k.tolist() == [1, 1, 3, 1, 1]
    # a tolerance as wide as a step: two candidates fit, nothing changes
    k = edge_steps(pa, pb, d_i, d_j, lab, ln, xy, 0, 39, fx, 6, 0.65)
    assert k.tolist() == [1, 1, 1, 1, 1]
    # the claimed step fits (within the tolerance): kept
    assert edge_steps(pa[:2], pb[:2], d_i[:2], d_j[:2], lab, ln, xy, 0, 39, fx, 6, 0.15).tolist() == [1, 1]
    # the step k = 3 would leave the pattern: no candidate, kept
    assert edge_steps(pa[2:3], pb[2:3], d_i[:1], d_j[:1], lab, ln, xy, 0, 4, fx, 6, 0.15).tolist() == [1]


def _chain_scene(skips):
    """The well-posed rig of test_recon_ambiguous_wellposed (dy 40 mm): a clean 7×7 patch and a chain along i-line 6
    whose edges claim one j-step each; the junctions of `skips` (j values) are missed, so those edges span more."""
    model, procam, q, edges, delta, truth = _a._patch(40.0, 12, 0.05, seed=2)
    key = {tuple(v): k for k, v in enumerate(truth.tolist())}
    patch = [key[(i, j)] for i in range(-9, -2) for j in range(-3, 4)]
    chain = [key[(6, j)] for j in range(-8, 9) if j not in skips]
    ids = np.array(patch + chain)
    pos = {k: n for n, k in enumerate(ids.tolist())}
    e_s, d_s = [], []
    for (a, b), d in zip(edges.tolist(), delta.tolist()):
        if a in pos and b in pos and pos[a] < len(patch) and pos[b] < len(patch):
            e_s.append((pos[a], pos[b])), d_s.append(d)
    for k in range(len(chain) - 1):
        e_s.append((len(patch) + k, len(patch) + k + 1)), d_s.append((0, 1))
    return model, procam, q[ids], np.array(e_s), np.array(d_s), truth[ids], np.arange(len(ids)) >= len(patch)


def test_a_chain_over_missed_crossings_is_restepped_and_labelled_right():
    # 17 junctions minus 5 missed in three places (one, two and two in a row): three edges claim one step where
    # the truth is 2, 3 and 3; a third of the chain sits on each offset, so it is ambiguous as a whole
    model, procam, q, e, d, truth, in_chain = _chain_scene({-5, 0, 1, 5, 6})
    none = _a._label(model, procam, q, e, d, skip_edges=False, frame_retry_limit=False)
    assert (none.labels[in_chain, 0] == UNLABELLED).all()
    # decision 0123's split alone labels the runs it can peel off (right), not the whole chain
    off = _a._label(model, procam, q, e, d, skip_edges=False)
    got = off.labels[:, 0] != UNLABELLED
    assert (off.labels[got] == truth[got]).all() and (~got[in_chain]).sum() >= 2
    on = _a._label(model, procam, q, e, d)
    assert on.stats["edges_restepped"] == 3
    assert (on.labels == truth).all()  # every junction, chain and patch, labelled right


def test_a_clean_chain_keeps_its_steps():
    # no missed crossing: no edge changes and the labels are those without the step
    model, procam, q, e, d, truth, in_chain = _chain_scene(set())
    on = _a._label(model, procam, q, e, d)
    off = _a._label(model, procam, q, e, d, skip_edges=False)
    assert on.stats.get("edges_restepped", 0) == 0 and off.stats == on.stats
    assert (on.labels == off.labels).all()
    ok = on.labels[:, 0] != UNLABELLED
    assert (on.labels[ok] == truth[ok]).all() and ok.sum() >= len(truth) - 1
