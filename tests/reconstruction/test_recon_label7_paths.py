"""Decision 0096 (label stage, round seven): the compiled paths against the code they replaced, bit for bit.

- `label_epipolar`'s first-round offsets of every component in one call (`_label_kernels.offset_choice_groups`)
  and the edge arrays made once, against the per-component `_choose_offset` loop of main at 7fa47dd, on the small
  scene with its true edges and with edge deltas corrupted (contradicting edges, split components, ambiguous ones);
- `piece_seeds.seed_one_sided`'s compiled steps against its NumPy version of main at 7fa47dd, called on the same
  traces inside `label_samples` (pitch 16 and pitch 24 scenes, labels kept on one side so that pieces get seeded).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from reconstruction import _label_kernels as K
from reconstruction import labelling as L
from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.geometry import camera_rays_proj
from reconstruction.labelling import (LEFT_OUT_REASONS, LabelOptions, TraceOptions, _choose_offset, _groups, _outlier_limit,
                                      _propagate, clean_edges, label_epipolar, label_samples)
from reconstruction.piece_seeds import _SIN_MIN_CROSSING, _k_refine, crossing_hits_traces, piece_ends
from reconstruction.rigmodel import UNLABELLED, RigModel, rig_model


def _old_label_epipolar(obs, model, xy_cam, options):
    """label_epipolar as it was before decision 0096 (main at 7fa47dd): clean_edges and _propagate on the filtered
    edges, each component's offset by `_choose_offset`."""
    M = len(obs.q_junction)
    labels = np.full((M, 2), UNLABELLED, np.int64)
    residual = np.full(M, np.nan)
    stats = {"components": 0, "components_labelled": 0, "ambiguous": 0, "out_of_pattern": 0, "out_of_depth_range": 0,
             "too_small": 0, "components_split": 0, "contradicting_edges": 0, "junctions_left_out": {}}
    left = dict.fromkeys(LEFT_OUT_REASONS, 0)
    edges, delta, removed = clean_edges(M, obs.edges, obs.edge_delta)
    stats["contradicting_edges"] = removed
    rel, comp = _propagate(M, edges, delta)
    lines = K.epipolar_from_rays(camera_rays_proj(model.procam, xy_cam), model.t_proj_cam_c)
    component = comp.copy()
    next_id = int(comp.max()) + 1 if M else 0
    groups = _groups(comp)
    stats["components"] = len(groups)
    work = [(g, 0) for g in groups]
    while work:
        members, rounds = work.pop()
        m = len(members)
        if rounds == 0 and m < options.min_component:
            left["component_too_small"] += m
            stats["too_small"] += 1
            continue
        if rounds > 0 and m < options.min_split_component:
            left["split_too_small"] += m
            continue
        ch = _choose_offset(model, rel[members], lines[members], xy_cam[members], options, stats)
        if ch.reason is not None:
            left[ch.reason] += m
            if ch.reason == "ambiguous":
                stats["ambiguous"] += 1
            continue
        r = ch.residual
        bad, n_bad = K.write_component(members, ch.labels, r, ch.inside, float(_outlier_limit(r, options)), labels, residual)
        stats["components_labelled"] += 1
        if n_bad == 0:
            continue
        outl = members[bad]
        if rounds >= options.max_split_rounds:
            left["residual_too_large"] += int((bad & ch.inside).sum())
            left["out_of_depth_range"] += int((bad & ~ch.inside).sum())
            continue
        stats["components_split"] += 1
        srt = np.sort(outl)
        pos_of = np.full(M, -1, np.intp)
        pos_of[srt] = np.arange(len(srt))
        sel = (pos_of[edges[:, 0]] >= 0) & (pos_of[edges[:, 1]] >= 0)
        sub_e = pos_of[edges[sel]].reshape(-1, 2)
        outl = srt
        sub_rel, sub_comp = _propagate(len(outl), sub_e, delta[sel])
        rel[outl] = sub_rel
        for g in _groups(sub_comp):
            component[outl[g]] = next_id
            next_id += 1
            work.append((outl[g], rounds + 1))
    stats["junctions_left_out"] = left
    return labels, residual, component, stats


def _old_seed_one_sided(
    q: np.ndarray,
    fam: np.ndarray,
    sid: np.ndarray,
    piece: np.ndarray,
    ts: np.ndarray,
    tangent: np.ndarray,
    index: np.ndarray,
    seed_jid: np.ndarray,
    *,
    model: RigModel,
    depth_range_mm: tuple[float, float],
    radius_px: float,
    grid: tuple,
    trim_px: float = 0.0,
    tol_px: float = 1.0,
    min_samples: int = 4,
    anchor: int = 3,
    rounds: int = 1,
    confirm_far: bool = True,
    refine: bool = True,
) -> dict:
    """Label unlabelled pieces whose crossing with a labelled line at one end names line k and whose crossing
    at the other end lands, on light sheet k, on the next line of the other family (module doc).

    q (P, 2) camera px, fam (P,) 1/2 of all samples; the traces as `labelling.label_samples` builds them: sid
    (n,) sample ids by piece and position, piece (n,) non-decreasing piece ids, ts (n,) position along the piece
    (px), tangent (n, 2) unit. index (P,) float (NaN: unlabelled) and seed_jid (P,) int are written in place
    (seed_jid: the junction of the labelled sample at the near end's crossing). radius_px: how far from a
    piece's end the crossings are searched (step 6's `cross_radius` junction steps); grid: the frame's bucket
    grid of the samples (`labelling._sample_grid`, cells ≥ radius_px). tol_px: projector px. Pieces shorter
    than min_samples are not tried. confirm_far=False skips step 2 (one-sided evidence alone, decision 0049's
    rule: for measurements only). refine=False takes the far crossing from the end tangents only (measurements).
    rounds: repetitions, newly labelled pieces serving as labelled lines. Returns counts: pieces and samples
    labelled, far ends rejected, far ends without a crossing."""
    stats = {"pieces": 0, "samples": 0, "far_rejected": 0, "far_missing": 0}
    n = len(piece)
    if n == 0:
        return stats
    n_p = int(piece[-1]) + 1
    z_lo, z_hi = float(depth_range_mm[0]), float(depth_range_mm[1])
    for _ in range(rounds):
        e, u, end_pos, labelled, _, _ = piece_ends(q, sid, piece, tangent, index, seed_jid, n_p, int(anchor))
        first, last = end_pos[:n_p], end_pos[n_p:]
        count = last - first + 1
        cand = np.flatnonzero(~labelled & (count >= min_samples))
        nc = len(cand)
        if nc == 0:
            break
        rows = np.concatenate((cand, cand + n_p))
        E = np.ascontiguousarray(e[rows])
        U = np.ascontiguousarray(u[rows])
        fe = fam[sid[end_pos[rows]]].astype(np.int64)
        # 1. each end's crossing with the nearest labelled sample of the other family, checked on its sheet m
        o, c = crossing_hits_traces(E, U, np.ones(2 * nc), fe, q, sid, tangent, fam, index, True, float(radius_px),
                                    _SIN_MIN_CROSSING, *grid)
        hit = o >= 0
        k_end = np.full(2 * nc, np.iinfo(np.int64).min, np.int64)
        m_end = np.zeros(2 * nc, np.int64)
        ok = np.zeros(2 * nc, bool)
        h = np.flatnonzero(hit)
        if len(h) == 0:
            break
        m = index[sid[o[h]]].astype(np.int64)
        _, z, kk, res = model.sheet_check(c[h], 3 - fe[h], m)
        ok[h] = (res <= tol_px) & (z >= z_lo) & (z <= z_hi)
        k_end[h] = kk
        m_end[h] = m
        # exactly one end checked; the other end has no labelled crossing at all
        a_ok, b_ok = ok[:nc], ok[nc:]
        a_hit, b_hit = hit[:nc], hit[nc:]
        one = (a_ok & ~b_hit) | (b_ok & ~a_hit)
        sel = np.flatnonzero(one)
        if len(sel) == 0:
            break
        near = np.where(a_ok[sel], sel, sel + nc)
        far = np.where(a_ok[sel], sel + nc, sel)
        k = k_end[near]
        # 2. the far end's crossing with any sample of the other family, checked on sheet k: the next line
        o2, c2 = crossing_hits_traces(np.ascontiguousarray(E[far]), np.ascontiguousarray(U[far]), np.ones(len(far)), fe[far], q, sid,
                                      tangent, fam, index, False, float(radius_px), _SIN_MIN_CROSSING, *grid)
        has2 = o2 >= 0
        stats["far_missing"] += int(np.sum(~has2))
        good = np.zeros(len(sel), bool) if confirm_far else np.ones(len(sel), bool)
        g = np.flatnonzero(has2)
        if len(g) and confirm_far:
            if refine:
                _k_refine(np.ascontiguousarray(end_pos[rows[far[g]]], np.int64), np.ascontiguousarray(o2[g], np.int64), g.astype(np.int64),
                          c2, first, last, piece, ts, q, sid, float(trim_px), int(anchor))
            _, z2, m2, res2 = model.sheet_check(c2[g], fe[far[g]], k[g])
            good[g] = (res2 <= tol_px) & (z2 >= z_lo) & (z2 <= z_hi) & (np.abs(m2 - m_end[near[g]]) == 1)
            stats["far_rejected"] += int(len(g) - good[g].sum())
        sel, near, k = sel[good], near[good], k[good]
        if len(sel) == 0:
            break
        # 3. the piece's samples inside the working volume on sheet k
        p_sel = cand[sel]
        lens = count[p_sel]
        pos = np.repeat(first[p_sel], lens) + (np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens))
        owner = np.repeat(np.arange(len(p_sel)), lens)
        _, zs, _, _ = model.sheet_check(q[sid[pos]], fam[sid[pos]], k[owner])
        inside = (zs >= z_lo) & (zs <= z_hi)
        all_in = np.bincount(owner, weights=~inside, minlength=len(p_sel)) == 0
        # write, leaving out the samples within trim_px of the piece's ends
        jv = seed_jid[sid[o[near]]]
        f0, l0 = first[p_sel][owner], last[p_sel][owner]
        keep = all_in[owner] & (np.minimum(ts[pos] - ts[f0], ts[l0] - ts[pos]) >= trim_px)
        w = pos[keep]
        if len(w) == 0:
            break
        index[sid[w]] = k[owner[keep]]
        seed_jid[sid[w]] = jv[owner[keep]]
        stats["pieces"] += int(np.unique(owner[keep]).size)
        stats["samples"] += int(len(w))
    return stats


def _frame(scene):
    model = rig_model(scene.procam, scene.pattern, scene.depth_range_mm)
    obs = extract_grid(scene.image, model)
    # decision 0108's residual clusters and decision 0130's cut of misfit edges came after 7fa47dd: the loop of that
    # commit does not have them
    opts = LabelOptions(depth_min_mm=scene.depth_range_mm[0], depth_max_mm=scene.depth_range_mm[1], residual_clusters=False,
                        cut_misfit_edges=False)
    return model, obs, opts


def _assert_labels_equal(new, old):
    labels, residual, component, stats = old
    assert np.array_equal(new.labels, labels)
    assert np.array_equal(new.residual, residual, equal_nan=True)
    assert np.array_equal(new.component, component)
    assert {k: v for k, v in new.stats.items() if k != "junctions_residual_clusters"} == stats
    assert new.stats["junctions_residual_clusters"] == 0


def test_label_epipolar_equals_the_per_component_loop(small_scene):
    model, obs, opts = _frame(small_scene)
    xy = model.cam_normalised(obs.q_junction)
    new = label_epipolar(obs, model, xy, options=opts)
    assert (new.labels[:, 0] != UNLABELLED).sum() > 100
    _assert_labels_equal(new, _old_label_epipolar(obs, model, xy, opts))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_label_epipolar_equals_the_per_component_loop_with_bad_edges(small_scene, seed):
    """Edge deltas corrupted at random: contradicting edges removed, components mixing two offsets split,
    ambiguous components retried on their inliers: every path of the loop, the same outputs."""
    model, obs, opts = _frame(small_scene)
    rng = np.random.default_rng(seed)
    d = np.array(obs.edge_delta, np.int64, copy=True)
    bad = rng.choice(len(d), size=max(1, len(d) // 12), replace=False)
    d[bad] += rng.integers(-1, 2, size=(len(bad), 2))
    obs = dataclasses.replace(obs, edge_delta=d)
    xy = model.cam_normalised(obs.q_junction)
    for o in (opts, dataclasses.replace(opts, min_component=4, max_split_rounds=1)):
        new = label_epipolar(obs, model, xy, options=o)
        old = _old_label_epipolar(obs, model, xy, o)
        _assert_labels_equal(new, old)
        if o is opts:  # the paths the loop takes beyond the first round were taken
            assert new.stats["components_split"] >= 1 and new.stats["ambiguous"] >= 1
    assert new.stats["contradicting_edges"] > 0 and new.stats["too_small"] > 0


def test_offset_choice_groups_equals_offset_choice_per_group(small_scene):
    model, obs, opts = _frame(small_scene)
    xy = np.ascontiguousarray(model.cam_normalised(obs.q_junction), np.float64)
    edges, delta, _ = clean_edges(len(xy), obs.edges, obs.edge_delta)
    rel, comp = _propagate(len(xy), edges, delta)
    lines = K.epipolar_from_rays(camera_rays_proj(model.procam, xy), model.t_proj_cam_c)
    order, bounds = L._group_bounds(comp)
    args = (model.xy_junction, int(model.index_min), int(model.index_max), float(model.fx_proj), int(opts.candidate_refs),
            float(opts.candidate_band_px), float(opts.min_inside_fraction), float(opts.residual_cap_px**2),
            model.procam.R_proj_cam, model.procam.t_proj_cam, float(opts.depth_min_mm), float(opts.depth_max_mm))
    M = len(xy)
    labels = np.full((M, 2), UNLABELLED, np.int64)
    residual = np.full(M, np.nan)
    st, nf, ok, s1, s2, ne, off, lim, r_all, in_all, written, bad, n_bad = K.offset_choice_groups(
        order, bounds, 2, rel, lines, xy, *args, float(opts.outlier_sigma), float(opts.max_residual_px), float(opts.noise_floor_px**2),
        float(opts.ambiguity_chi2), float(opts.min_rms_ratio**2), labels, residual)
    labels_ref = np.full((M, 2), UNLABELLED, np.int64)
    residual_ref = np.full(M, np.nan)
    n_ok = 0
    n_written = 0
    for g in range(len(bounds) - 1):
        mem = order[bounds[g] : bounds[g + 1]]
        if len(mem) < 2:
            assert st[g] == -1
            continue
        ref = K.offset_choice(np.ascontiguousarray(rel[mem]), np.ascontiguousarray(lines[mem]), np.ascontiguousarray(xy[mem]), *args)
        assert (st[g], nf[g], ok[g], s1[g], s2[g], ne[g]) == tuple(ref[:6])
        assert np.array_equal(off[g], ref[6])
        if ref[2]:
            n_ok += 1
            assert np.array_equal(r_all[bounds[g] : bounds[g + 1]], ref[7], equal_nan=True)
            assert np.array_equal(in_all[bounds[g] : bounds[g + 1]], ref[8])
            assert lim[g] == _outlier_limit(ref[7], opts)
            s1g, s2g = float(ref[3]), float(ref[4])
            sigma2 = max(s1g, opts.noise_floor_px**2)
            ambiguous = ref[5] * (s2g - s1g) / sigma2 < opts.ambiguity_chi2 or s2g < opts.min_rms_ratio**2 * sigma2
            assert written[g] == (not ambiguous)
            if written[g]:
                n_written += 1
                b_ref, nb_ref = K.write_component(mem, np.ascontiguousarray(rel[mem]) + ref[6], ref[7], ref[8], float(_outlier_limit(ref[7], opts)),
                                                  labels_ref, residual_ref)
                assert np.array_equal(bad[bounds[g] : bounds[g + 1]], b_ref) and n_bad[g] == nb_ref
        else:
            assert np.isnan(lim[g]) and not written[g]
    assert n_ok >= 1 and n_written >= 1
    assert np.array_equal(labels, labels_ref) and np.array_equal(residual, residual_ref, equal_nan=True)


@pytest.mark.parametrize("scene_name", ["small_scene", "small_scene_pitch16"])
def test_seed_one_sided_equals_the_numpy_version(request, monkeypatch, scene_name):
    """Junction labels kept on the left of a slanted border: pieces at the patch's border are seeded from one
    crossing. The compiled seed_one_sided and the NumPy one of 7fa47dd on the same traces: index, seed_jid and
    stats equal."""
    s = request.getfixturevalue(scene_name)
    model, obs, opts = _frame(s)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction), options=opts).labels.copy()
    lab[obs.q_junction[:, 0] + 0.4 * obs.q_junction[:, 1] >= 380.0] = UNLABELLED
    sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))
    calls = []
    real = L.seed_one_sided

    def both(q, fam, sid, piece, ts, tangent, index, seed_jid, **kw):
        i_old, j_old = index.copy(), seed_jid.copy()
        st_old = _old_seed_one_sided(q, fam, sid, piece, ts, tangent, i_old, j_old, **kw)
        st_new = real(q, fam, sid, piece, ts, tangent, index, seed_jid, **kw)
        calls.append((np.array_equal(index, i_old, equal_nan=True), np.array_equal(seed_jid, j_old), st_new == st_old, st_new))
        return st_new

    monkeypatch.setattr(L, "seed_one_sided", both)
    label_samples(obs, lab, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]),
                  options=dataclasses.replace(TraceOptions(), piece_seeds=True, piece_junctions=False), model=model,
                  depth_range_mm=s.depth_range_mm, image=s.image, line_width_px=model.line_width_cam_px)
    assert len(calls) == 1
    same_index, same_jid, same_stats, st = calls[0]
    assert same_index and same_jid and same_stats
    assert st["samples"] > 0
