"""Glue round five (decision 0087): each new kernel against the NumPy code it replaced, on seeded random
inputs that include the branches the harness scenes rarely reach (NaN positions, cells outside the grid,
zero and NaN steps, negative component ids, empty inputs)."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction import _extract_kernels as xk
from reconstruction import _label_kernels as lk
from reconstruction import labelling
from reconstruction.trace_ends import _facing_candidates

UNL = np.iinfo(np.int64).min // 2


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


# --- extraction ------------------------------------------------------------------------------------------


def _edge_reference(sid, a_j, b_j, fam_s, mid, dq, elen, J, cell_px, n1, n2, M):
    """extract_grid's edge step before 0087: RigModel.lookup, einsum, sign, masks, edge_skips."""
    gh, gw = J.shape[:2]
    with np.errstate(invalid="ignore"):
        c = np.clip(np.rint(mid[:, 0] / cell_px).astype(np.intp), 0, gw - 1)
        r = np.clip(np.rint(mid[:, 1] / cell_px).astype(np.intp), 0, gh - 1)
        Jpc = J[r, c]
        dq_proj = np.einsum("nij,nj->ni", Jpc, dq)
        n_other = np.where(fam_s == 1, n2, n1)
        s_other = np.sign(dq_proj[:, 1] - n_other * dq_proj[:, 0]).astype(np.int64)
    delta = np.zeros((len(sid), 2), np.int64)
    delta[:, 0] = np.where(fam_s == 2, s_other, 0)
    delta[:, 1] = np.where(fam_s == 1, s_other, 0)
    good = s_other != 0
    skip = xk.edge_skips(a_j, b_j, fam_s.astype(np.intp) - 1, elen, M)
    n_skip = int((good & skip).sum())
    good &= ~skip
    return np.column_stack([a_j, b_j])[good], fam_s[good], delta[good], sid[good], n_skip


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_edge_steps_equal_the_numpy_steps(seed):
    rng = np.random.default_rng(seed)
    gh, gw, cell = 13, 17, 8
    J = rng.normal(size=(gh, gw, 2, 2)) * rng.uniform(0.2, 3.0, size=(gh, gw, 1, 1))
    J.setflags(write=False)  # as RigModel holds it
    n, M = 400, 120
    a_j = rng.integers(0, M, n).astype(np.int64)
    b_j = rng.integers(0, M, n).astype(np.int64)
    fam_s = rng.integers(1, 3, n).astype(np.int8)
    sid = rng.permutation(n * 3)[:n].astype(np.int64)
    mid = np.column_stack([rng.uniform(-30, gw * cell + 30, n), rng.uniform(-30, gh * cell + 30, n)])
    mid[::37] = np.nan  # NaN cell: NumPy's cast gives INT64_MIN, clipped to 0
    mid[5] = (1e30, -1e30)  # beyond int64
    mid[6] = (4.0 * cell + 0.5 * cell, 2.5 * cell)  # rint's half-even case
    dq = rng.normal(size=(n, 2)) * 20
    dq[::29] = 0.0  # zero step: no edge
    dq[7] = (np.nan, 1.0)  # NaN step: sign NaN, cast INT64_MIN (an "edge" with that delta)
    elen = np.hypot(dq[:, 0], dq[:, 1]) + rng.uniform(0, 5, n)
    n1, n2 = 0.21, -3.7
    want = _edge_reference(sid, a_j, b_j, fam_s, mid, dq, elen, J, float(cell), n1, n2, M)
    got = xk.edge_steps(sid, a_j, b_j, fam_s, mid, dq, elen, J, float(cell), n1, n2, M)
    for g, w in zip(got[:4], want[:4]):
        assert _same(g, w)
    assert got[4] == want[4]
    assert 0 < len(got[0]) < n and got[4] > 0  # both filters did something
    assert (got[2] == np.iinfo(np.int64).min).any()  # the NaN step's cast reproduced


def test_edge_steps_empty():
    J = np.ones((2, 2, 2, 2))
    e = np.zeros(0, np.int64)
    got = xk.edge_steps(e, e, e, np.zeros(0, np.int8), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), J, 8.0, 0.1, 2.0, 0)
    assert got[0].shape == (0, 2) and got[2].shape == (0, 2) and got[4] == 0


def test_keep_crossings_and_kept_junctions_equal_the_masks():
    rng = np.random.default_rng(4)
    ns = 300
    n_ring = rng.integers(0, 5, size=(ns, 2)).astype(np.int64)
    seeds = rng.uniform(0, 900, size=(ns, 2))
    score = rng.normal(size=ns).astype(np.float32)
    crossing = (n_ring >= 2).all(axis=1)
    remap = np.full(ns, -1, np.int64)
    remap[np.nonzero(crossing)[0]] = np.arange(int(crossing.sum()))
    got = xk.keep_crossings(n_ring, seeds, score)
    kept = seeds[crossing]
    want = (remap, kept, score[crossing], kept[:, 0].copy(), kept[:, 1].copy(), kept[:, 0].astype(np.float32),
            kept[:, 1].astype(np.float32))
    for g, w in zip(got[:7], want):
        assert _same(g, w)
    assert got[7] == int((~crossing).sum()) > 0

    K = len(kept)
    valid = rng.random(K) < 0.6
    qj = rng.uniform(0, 900, size=(K, 2))
    dr = rng.normal(size=(K, 2, 2))
    rms = rng.uniform(0, 1, size=(K, 2))
    seg_seed = rng.integers(-1, K, size=(500, 2)).astype(np.int64)
    for scale in (1, 2):
        new_id = np.full(K + 1, -1, np.int64)
        new_id[:K][valid] = np.arange(int(valid.sum()))
        want = (new_id, qj[valid], dr[valid], rms[valid] * scale, new_id[seg_seed])
        got = xk.kept_junctions(valid, qj, dr, rms, scale, seg_seed)
        for g, w in zip(got, want):
            assert _same(g, w)


def test_samples_f64_equal_the_casts():
    rng = np.random.default_rng(5)
    qx, qy, st = (rng.uniform(-5, 1300, 1000).astype(np.float32) for _ in range(3))
    q, s64 = xk.samples_f64(qx, qy, st)
    assert _same(q, np.column_stack([qx, qy]).astype(np.float64)) and _same(s64, st.astype(np.float64))


# --- labelling ---------------------------------------------------------------------------------------------


def test_label_sample_passes_equal_the_masks():
    rng = np.random.default_rng(6)
    P = 5000
    valid = rng.random(P) < 0.8
    near_other = rng.random(P) < 0.3
    seed = np.where(rng.random(P) < 0.2, rng.integers(-5, 30, P), UNL).astype(np.int64)
    k_idx, n_mix, n_seeds = lk.kept_samples(valid, near_other, seed, UNL)
    kept = valid & ~near_other
    assert _same(k_idx, np.flatnonzero(kept))
    assert n_mix == int((valid & near_other).sum()) and n_seeds == int(np.count_nonzero((seed != UNL) & kept)) > 0

    index = np.where(rng.random(P) < 0.5, rng.integers(0, 40, P).astype(np.float64), np.nan)
    sid = rng.permutation(P)[:3000]
    g, n_un = lk.labelled_positions(index, sid)
    got = np.isfinite(index[sid])
    assert _same(g, np.flatnonzero(got)) and n_un == int((~got).sum())

    seen = np.isfinite(index) & (rng.random(P) < 0.7)
    lab, new_s = lk.newly_labelled(index, seen, True)
    assert _same(lab, np.isfinite(index)) and _same(new_s, np.flatnonzero(np.isfinite(index) & ~seen)) and len(new_s)
    lab, new_s = lk.newly_labelled(index, np.zeros(0, np.bool_), False)
    assert _same(lab, np.isfinite(index)) and len(new_s) == 0


def _groups_reference(comp):
    order = np.argsort(comp, kind="stable")
    bounds = np.flatnonzero(np.diff(np.concatenate([[-1], comp[order], [-2]])))
    return [order[bounds[k] : bounds[k + 1]] for k in range(len(bounds) - 1)]


@pytest.mark.parametrize("neg", [False, True])
def test_groups_equal_the_stable_argsort(neg):
    rng = np.random.default_rng(8)
    comp = rng.integers(0, 60, 700).astype(np.int64) * 3  # gaps between ids
    if neg:
        comp[::50] = -4  # the NumPy path
    got = labelling._groups(comp)
    want = _groups_reference(comp)
    assert len(got) == len(want) > 10
    assert all(_same(np.asarray(g, np.int64), np.asarray(w, np.int64)) for g, w in zip(got, want))
    order, bounds = lk.group_order(comp)
    assert (len(order) == 0) == neg


def test_write_component_equals_the_masks():
    rng = np.random.default_rng(9)
    M, m = 400, 150
    members = rng.permutation(M)[:m].astype(np.intp)
    lab = rng.integers(-20, 20, size=(m, 2)).astype(np.int64)
    r = rng.exponential(0.5, m)
    r[::13] = np.nan
    r[::17] = np.inf
    inside = rng.random(m) < 0.9
    limit = 0.8
    labels = np.full((M, 2), UNL, np.int64)
    residual = np.full(M, np.nan)
    bad, nb = lk.write_component(members, lab, r, inside, limit, labels, residual)
    want_bad = ~np.isfinite(r) | (r > limit) | ~inside
    w_labels = np.full((M, 2), UNL, np.int64)
    w_res = np.full(M, np.nan)
    good = ~want_bad
    w_labels[members[good]] = lab[good]
    w_res[members[good]] = r[good]
    assert _same(bad, want_bad) and nb == int(want_bad.sum()) > 0
    assert _same(labels, w_labels) and _same(residual, w_res)


def test_crossing_hits_equal_the_gathers():
    rng = np.random.default_rng(10)
    P, R = 3000, 500
    index = np.where(rng.random(P) < 0.6, rng.integers(-3, 40, P).astype(np.float64), np.nan)
    sid = rng.permutation(P)
    o = np.where(rng.random(R) < 0.4, rng.integers(0, P, R), -1).astype(np.intp)
    c = rng.uniform(0, 1000, size=(R, 2))
    fe = rng.integers(1, 3, 2 * R).astype(np.int64)
    redo = np.sort(rng.permutation(2 * R)[:R]).astype(np.intp)
    sel_w = np.flatnonzero(o >= 0)
    with np.errstate(invalid="ignore"):
        m_w = index[sid[o[sel_w]]].astype(np.int64)  # NaN: INT64_MIN, as the kernel
    for have in (True, False):
        sel, o_sel, c_sel, f_other, m = lk.crossing_hits(o, c, redo, have, fe, index, sid)
        ends = redo[sel_w] if have else sel_w
        assert _same(sel, ends.astype(np.intp)) and _same(o_sel, o[sel_w]) and _same(c_sel, c[sel_w])
        assert _same(f_other, (3 - fe[ends]).astype(np.intp)) and _same(m, m_w)
    sel, o_sel, c_sel, f_other, m = lk.crossing_hits(o, c, redo, True, fe, index, sid)
    K = len(sel)
    kk = rng.integers(0, 40, K).astype(np.int64)
    res = rng.exponential(1.0, K)
    z = rng.uniform(300, 1500, K)
    res[::7] = np.nan
    seed_jid = rng.integers(-1, 300, P).astype(np.int64)
    k_end = np.full(2 * R, UNL, np.int64)
    jid_end = np.full(2 * R, -1, np.int64)
    k_w, j_w = k_end.copy(), jid_end.copy()
    lk.crossing_hits_write(sel, o_sel, kk, res, z, 1.2, 500.0, 1400.0, k_end, jid_end, seed_jid, sid)
    good = (res <= 1.2) & (z >= 500.0) & (z <= 1400.0)
    k_w[sel[good]] = kk[good]
    j_w[sel[good]] = seed_jid[sid[o_sel[good]]]
    assert _same(k_end, k_w) and _same(jid_end, j_w) and 0 < good.sum() < K


def _facing_reference(sid, piece, index, q, fam, pos_of, x0, y0, cell, gw, gh):
    n = len(sid)
    ends = np.zeros(n, bool)
    if n:
        ends[0] = ends[-1] = True
        ends[1:] |= piece[1:] != piece[:-1]
        ends[:-1] |= piece[1:] != piece[:-1]
    cand = np.concatenate([sid[ends & np.isfinite(index[sid])], np.flatnonzero((pos_of < 0) & np.isfinite(index))])
    xx = np.clip(np.floor((q[cand, 0] - x0) / cell).astype(np.intp), 0, gw - 1)
    yy = np.clip(np.floor((q[cand, 1] - y0) / cell).astype(np.intp), 0, gh - 1)
    cid = yy * gw + xx
    order = np.argsort(cid, kind="stable")
    out = cand[order]
    start = np.concatenate([[0], np.cumsum(np.bincount(cid, minlength=gw * gh))])
    rec = np.column_stack([q[out, 0], q[out, 1], fam[out].astype(np.float64), index[out]])
    one = np.full((gw * gh, 2), -1, np.int32)
    for s, b in zip(out, cid[order]):
        f, v = fam[s] - 1, int(index[s])
        one[b, f] = v if one[b, f] == -1 else (one[b, f] if one[b, f] == v else -2)
    return start, out, rec, one


def test_facing_candidates_equal_the_gathered_lists():
    rng = np.random.default_rng(11)
    P = 4000
    q = rng.uniform(0, 400, size=(P, 2))
    fam = rng.integers(1, 3, P).astype(np.int64)
    index = np.where(rng.random(P) < 0.7, rng.integers(0, 6, P).astype(np.float64), np.nan)
    sid = rng.permutation(P)[:2500].astype(np.int64)
    piece = np.sort(rng.integers(0, 300, len(sid))).astype(np.int64)
    piece = np.unique(piece, return_inverse=True)[1].astype(np.int64)  # 0 .. n_pieces − 1, no gaps
    pos_of = np.full(P, -1, np.int64)
    pos_of[sid] = np.arange(len(sid))
    args = (sid, piece, index, q, fam, pos_of, -2.0, -3.0, 37.0, 12, 12)
    got = _facing_candidates(*args)
    want = _facing_reference(*args)
    for g, w in zip(got, want):
        assert np.array_equal(np.asarray(g), np.asarray(w))
    assert len(got[1]) > 300 and (got[3] == -2).any()
    assert np.isfinite(got[2][:, 3]).all()


def test_label_arrays_equal_the_numpy_allocations():
    rng = np.random.default_rng(12)
    q = rng.uniform(0, 1000, size=(777, 2))
    fam8 = rng.integers(0, 3, 777).astype(np.int8)
    from reconstruction.rigmodel import UNLABELLED

    # decision 0150: the families int8, index float32, seed_jid and seed int32 (label_samples widens what it returns;
    # its sentinel UNLABELLED is the int32 minimum)
    fam, index, q_out, seed_jid, seed = lk.label_arrays(q, fam8, UNLABELLED)
    assert _same(fam, fam8) and _same(index, np.full(777, np.nan, np.float32)) and _same(q_out, q)
    assert _same(seed_jid, np.full(777, -1, np.int32)) and _same(seed, np.full(777, UNLABELLED, np.int32))
    q_out[0, 0] = -1.0
    assert q[0, 0] != -1.0  # a copy


# --- continuation._check_pieces ------------------------------------------------------------------------------


def test_check_piece_kernels_equal_the_numpy_steps():
    from reconstruction import _link_kernels as kk

    rng = np.random.default_rng(13)
    n_p, P, n = 200, 3000, 2500
    e = rng.uniform(0, 900, size=(2 * n_p, 2))
    u = rng.normal(size=(2 * n_p, 2))
    f_e = rng.integers(1, 3, 2 * n_p).astype(np.int64)
    cand = np.sort(rng.permutation(n_p)[:70]).astype(np.intp)
    nc = len(cand)
    k_of = np.where(rng.random(n_p) < 0.9, rng.integers(-5, 40, n_p).astype(np.float64), np.nan)
    # the ends
    end_ids = np.concatenate([cand, cand + n_p])
    E, U, fe = kk.check_ends(cand, n_p, e, u, f_e)
    assert _same(E, e[end_ids]) and _same(U, u[end_ids]) and _same(fe, f_e[end_ids])
    # the hits
    o = np.where(rng.random(2 * nc) < 0.6, rng.integers(0, n, 2 * nc), -1).astype(np.intp)
    c = rng.uniform(0, 900, size=(2 * nc, 2))
    pe = np.concatenate([cand, cand])
    sel_w = np.flatnonzero(o >= 0)
    sel, c_sel, f_sel, k_sel = kk.check_hits(o, c, fe, k_of, cand)
    with np.errstate(invalid="ignore"):
        k_w = k_of[pe[sel_w]].astype(np.int64)
    assert _same(sel, sel_w.astype(np.intp)) and _same(c_sel, c[sel_w]) and _same(f_sel, fe[sel_w]) and _same(k_sel, k_w)
    # the verdicts
    res = rng.exponential(1.0, len(sel))
    res[::9] = np.nan
    good = kk.check_verdicts(o, sel, res, 1.1, nc)
    evaluated = o >= 0
    passed = np.zeros(2 * nc, bool)
    passed[sel] = res <= 1.1
    evaluated, passed = evaluated.reshape(2, nc), passed.reshape(2, nc)
    good_w = ~(evaluated & ~passed).any(axis=0) & evaluated.any(axis=0)
    assert _same(good, good_w) and 0 < good.sum() < nc
    # the samples and the depth test
    q = rng.uniform(0, 900, size=(P, 2))
    fam = rng.integers(1, 3, P).astype(np.intp)
    sid = rng.permutation(P)[:n].astype(np.int64)
    piece = np.sort(rng.integers(0, n_p, n)).astype(np.int64)
    pos = np.sort(rng.permutation(n)[:400]).astype(np.intp)
    q_pos, f_pos, k_pos = kk.check_samples(pos, q, sid, fam, piece, k_of)
    with np.errstate(invalid="ignore"):
        k_w = k_of[piece[pos]].astype(np.int64)
    assert _same(q_pos, q[sid[pos]]) and _same(f_pos, fam[sid[pos]]) and _same(k_pos, k_w)
    z = rng.uniform(200, 1600, len(pos))
    z[::31] = np.nan
    g1 = good.copy()
    kk.check_depth(g1, cand, pos, piece, z, 300.0, 1500.0, n_p)
    out = ~((z >= 300.0) & (z <= 1500.0))
    bad = np.zeros(n_p, bool)
    bad[piece[pos[out]]] = True
    assert _same(g1, good & ~bad[cand]) and (g1 != good).any()


# --- label_epipolar's offset choice ---------------------------------------------------------------------------


def _offset_choice_reference(model, rel, ln, xy_cam, refs, band, frac, cap2, z_min, z_max):
    """_choose_offset's three kernel calls as before 0087."""
    status, off, score, ranked, n_eff = lk.offset_scores(rel, ln, model.xy_junction, int(model.index_min),
                                                         int(model.index_max), float(model.fx_proj), refs, band, frac, cap2)
    if status != 0:
        return status, 0, False, None
    top = ranked[: min(len(ranked), 16)]
    pass_k, n_fail, inside = lk.offset_depth_walk(rel, off, top, xy_cam, model.xy_junction, int(model.index_min),
                                                  int(model.index_max), model.procam.R_proj_cam, model.procam.t_proj_cam,
                                                  z_min, z_max, frac)
    if pass_k[0] < 0:
        return status, n_fail, False, None
    best = int(top[pass_k[0]])
    s2 = float(score[top[pass_k[1]]]) if pass_k[1] >= 0 else cap2
    r_full = lk.offset_residuals(rel, int(off[best, 0]), int(off[best, 1]), ln, model.xy_junction, int(model.index_min),
                                 int(model.index_max), float(model.fx_proj))
    return status, n_fail, True, (float(score[best]), s2, n_eff, off[best], r_full, inside)


def test_offset_choice_equals_the_three_calls():
    from calibration.models import Intrinsics, ProCam, look_at
    from reconstruction.geometry import epipolar_lines
    from reconstruction.patterns import GridPattern
    from reconstruction.rigmodel import rig_model

    cam = Intrinsics(640, 480, np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1]]), np.zeros(5))
    prj = Intrinsics(800, 600, np.array([[1000.0, 0, 399.5], [0, 1000.0, 299.5], [0, 0, 1]]), np.zeros(5))
    t = np.array([180.0, 60.0, 40.0])
    model = rig_model(ProCam(cam, prj, look_at(t, np.array([0, 0, 800.0])), t), GridPattern(), (500.0, 1200.0))
    rng = np.random.default_rng(23)
    outcomes = set()
    for trial in range(200):
        m = int(rng.integers(1, 40))
        # junctions of a plane: projector junctions (i, j) + a random offset, seen by the camera
        ij = rng.integers(model.index_min + 3, model.index_max - 3, 2) + rng.integers(-3, 4, (m, 2))
        xy_p = model.junction_xy(ij[:, 0], ij[:, 1])
        z = rng.uniform(600, 1100)
        p_proj = np.column_stack([xy_p * z, np.full(m, z)])
        p_cam = (p_proj - t) @ model.procam.R_proj_cam  # R^T (p − t)
        xy_cam = p_cam[:, :2] / p_cam[:, 2:3] + rng.normal(0, 2e-4, (m, 2))
        ln = epipolar_lines(model.procam, xy_cam)
        rel = (ij - ij[0]).astype(np.int64)
        if trial % 10 == 9:  # a component wider than the pattern: no admissible offset (status ≠ 0)
            rel[-1] += 4 * (model.index_max - model.index_min)
            rel[: m // 2] -= 4 * (model.index_max - model.index_min)
        z_min, z_max = (500.0, 1200.0) if trial % 3 else tuple(sorted(rng.uniform(300, 1500, 2)))
        frac = float(rng.choice([0.5, 0.9]))
        want = _offset_choice_reference(model, rel, ln, xy_cam, 4, 1.5, frac, 9.0, z_min, z_max)
        got = lk.offset_choice(rel, ln, xy_cam, model.xy_junction, int(model.index_min), int(model.index_max),
                               float(model.fx_proj), 4, 1.5, frac, 9.0, model.procam.R_proj_cam, model.procam.t_proj_cam,
                               z_min, z_max)
        assert got[0] == want[0] and got[1] == want[1] and got[2] == want[2]
        if want[2]:
            s1, s2, n_eff, off_best, r_full, inside = want[3]
            assert got[3] == s1 and got[4] == s2 and got[5] == n_eff
            assert _same(got[6], off_best.astype(np.int64)) and _same(got[7], r_full) and _same(got[8], inside)
        outcomes.add((int(want[0] != 0), bool(want[2]), bool(want[2]) and want[3][1] == 9.0))
    assert {(0, True, False), (0, True, True), (0, False, False), (1, False, False)} <= outcomes, outcomes


def test_round_state_kernels_equal_the_fancy_indexing():
    rng = np.random.default_rng(14)
    n_pieces, nt = 300, 120
    todo = np.sort(rng.permutation(n_pieces)[:nt]).astype(np.intp)
    bd_all = rng.uniform(0, 50, 2 * n_pieces)
    bd_all[::7] = np.inf
    bk_all = rng.integers(-1, 900, 2 * n_pieces).astype(np.intp)
    k_all = rng.integers(-3, 40, 2 * n_pieces).astype(np.int64)
    j_all = rng.integers(-1, 500, 2 * n_pieces).astype(np.int64)
    keys = np.concatenate([todo, todo + n_pieces])
    bd, bk, ke, je = lk.round_state_gather(todo, n_pieces, bd_all, bk_all, k_all, j_all)
    assert _same(bd, bd_all[keys]) and _same(bk, bk_all[keys]) and _same(ke, k_all[keys]) and _same(je, j_all[keys])
    # the round changes some ends, then writes back
    changed = rng.random(2 * nt) < 0.3
    e = rng.uniform(0, 900, (2 * nt, 2))
    te = rng.normal(size=(2 * nt, 2))
    sign = np.where(rng.random(2 * nt) < 0.5, -1.0, 1.0)
    k_w, j_w = ke.copy(), je.copy()
    redo, e_r, te_r, s_r, b_r = lk.redo_rows(changed, e, te, sign, bk, ke, je, UNL)
    r = np.flatnonzero(changed)
    k_w[r] = UNL
    j_w[r] = -1
    assert _same(redo, r.astype(np.intp)) and _same(e_r, e[r]) and _same(te_r, te[r]) and _same(s_r, sign[r]) and _same(b_r, bk[r])
    assert _same(ke, k_w) and _same(je, j_w) and len(r) > 10
    all_w = [a.copy() for a in (bd_all, bk_all, k_all, j_all)]
    for a, v in zip(all_w, (bd, bk, ke, je)):
        a[keys] = v
    lk.round_state_scatter(todo, n_pieces, bd, bk, ke, je, bd_all, bk_all, k_all, j_all)
    assert all(_same(a, w) for a, w in zip((bd_all, bk_all, k_all, j_all), all_w))


def test_refit_inputs_equal_the_gathers():
    from reconstruction.junction_arms import _refit_inputs

    rng = np.random.default_rng(15)
    P, ns = 3000, 200
    cand = np.sort(rng.permutation(ns)[:40]).astype(np.int64)
    arm_of = rng.integers(-1, ns, P).astype(np.intp)
    on_cand = np.flatnonzero(np.isin(arm_of, cand))
    kept = np.sort(rng.permutation(on_cand)[: len(on_cand) // 2]).astype(np.int64)
    fam = rng.integers(1, 3, P).astype(np.int8)
    qx, qy, nx, ny = (rng.normal(size=P).astype(np.float32) for _ in range(4))
    sx, sy = rng.uniform(0, 900, ns), rng.uniform(0, 900, ns)
    compact = np.full(ns, -1, np.int64)
    compact[cand] = np.arange(len(cand))
    want = (compact[arm_of[kept]], fam[kept], qx[kept], qy[kept], nx[kept], ny[kept], sx[cand], sy[cand])
    got = _refit_inputs(cand, kept, arm_of, fam, qx, qy, nx, ny, sx, sy, ns)
    assert all(_same(g, w) for g, w in zip(got, want)) and len(kept) > 50


def test_continuation_masks_equal_the_numpy_steps():
    from reconstruction import _link_kernels as kk

    rng = np.random.default_rng(16)
    n_p = 400
    a = rng.integers(0, n_p, 150).astype(np.intp)
    b = rng.integers(0, n_p, 150).astype(np.intp)
    labelled = rng.random(n_p) < 0.3
    k_of = np.where(rng.random(n_p) < 0.8, rng.integers(0, 30, n_p).astype(np.float64), np.nan)
    linked = np.zeros(n_p, bool)
    linked[a] = True
    linked[b] = True
    cand = kk.linked_unlabelled(n_p, a, b, labelled, k_of)
    assert _same(cand, np.flatnonzero(linked & ~labelled & np.isfinite(k_of))) and len(cand) > 20
    good = rng.random(len(cand)) < 0.6
    keep, new, n_failed = kk.checked_pieces(labelled, cand, good)
    keep_w = labelled.copy()
    keep_w[cand[good]] = True
    new_w = np.zeros(n_p, bool)
    new_w[cand[good]] = True
    assert _same(keep, keep_w) and _same(new, new_w) and n_failed == int((~good).sum())
    k2 = np.where(rng.random(n_p) < 0.7, k_of, np.nan)
    left = kk.with_index(new, k2)
    new_w &= np.isfinite(k2)
    assert _same(new, new_w) and left == bool(new_w.any()) and left
    assert not kk.with_index(np.zeros(n_p, bool), k2)
