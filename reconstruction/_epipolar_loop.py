"""`labelling.label_epipolar`'s per-component work loop in one compiled call (decision 0161).

The Python loop (`labelling._work_loop_py`, kept as the reference: `LabelOptions.compiled_loop=False`) pops a
component, applies decision 0134's lone-junction floor, 0146's re-step of accepted components, `_choice_of`'s tests
(the ambiguity test, 0122's noise split, 0125's re-step and 0130's cuts, 0123's inlier retry), writes the inliers, takes
out 0108's residual clusters and splits at the outliers; each step called five to ten kernels and ~30 NumPy
operations per component (~35 µs, decision 0158). `work_loop` does the same steps in the same order with the same
kernels (`offset_choice_b`, `component_edge_steps`, `edge_misfits`, `clean_edges_walk`, `propagate`, `group_order`,
`neighbour_noise2`, `elevated_pieces`, `write_component`, `median_finite`) on the same arguments, so its outputs are the
Python loop's bit for bit. Python's max(a, b) and min(a, b) are written out as they evaluate (the first argument
unless the second is strictly larger / smaller). The kept edges' adjacency is built at its first use, as `_Graph`
builds it, with keep as it is at that moment.

The work list is a stack in one buffer: a popped component's pieces are subsets of it and are pushed where it lay.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._ambiguity_kernels import component_edge_steps, neighbour_noise2
from reconstruction._jit import njit
from reconstruction._label_kernels import (clean_edges_walk, gather_members, group_order, median_finite, offset_choice_b, propagate,
                                          write_component)
from reconstruction.edge_cuts import edge_misfits
from reconstruction.residual_clusters import elevated_pieces, kept_adjacency

# counts returned in `work_loop`'s stats array (labelling maps them to its stats keys)
S_LABELLED, S_AMBIGUOUS, S_OUT_OF_PATTERN, S_OUT_OF_DEPTH, S_TOO_SMALL, S_SPLIT, S_CLUSTERS = 0, 1, 2, 3, 4, 5, 6
S_EDGES_RESTEPPED, S_COMPONENTS_RESTEPPED, S_RESTEPPED_ACCEPTED, S_NOISE_SPLIT, S_EDGES_CUT = 7, 8, 9, 10, 11
N_STATS = 12
# left-out counts, in labelling.LEFT_OUT_REASONS' order
L_AMBIGUOUS, L_NO_OFFSET, L_TOO_SMALL, L_RESIDUAL, L_DEPTH, L_SPLIT_SMALL = 0, 1, 2, 3, 4, 5


@njit
def _outlier_limit(r, outlier_sigma, max_residual_px):
    """labelling._outlier_limit."""
    med = median_finite(r)
    sigma_hat = 1.4826 * med if math.isfinite(med) else np.inf
    lim = outlier_sigma * sigma_hat
    if max_residual_px > lim:
        lim = max_residual_px
    return lim


@njit
def _is_ambiguous(n_eff, s1, s2, noise_floor2, chi2, rms_ratio2):
    sigma2 = s1
    if noise_floor2 > sigma2:
        sigma2 = noise_floor2
    return n_eff * (s2 - s1) / sigma2 < chi2 or s2 < rms_ratio2 * sigma2


@njit
def _shared_error(members, rm, lm, off0, off1, s1, s2, n_eff, xy_junction, index_min, index_max, fx, start, nbr, gpos, cap2,
                  noise_floor2, chi2, rms_ratio2):
    """labelling._shared_error_test past its likelihood condition (the caller checks that and builds the adjacency)."""
    noise2, n_edges = neighbour_noise2(members, rm, off0, off1, lm, xy_junction, index_min, index_max, fx, start, nbr, gpos, cap2)
    if n_edges == 0 or not math.isfinite(noise2):
        return False
    d = s1 - noise2
    if noise_floor2 > d:
        d = noise_floor2
    return s2 - noise2 >= rms_ratio2 * d


@njit
def _restep(members, off0, off1, cut, rpos, keep, edges_all, delta_all, rel, lines, xy_junction, index_min, index_max, fx,
            skip_max_steps, skip_tol, cut_tol, a_all, b_all, start, nbr, have_adj, gpos):
    """labelling's `_restep(members, off, cut_ok)` (cut: cut_misfit_edges and cut_ok): keep, delta_all and rel updated
    in place as it updates them. Returns (did (False: `_restep` returned None), edges re-stepped, edges cut, the
    pieces as members[p_order[p_bounds[q]:p_bounds[q + 1]]], and the adjacency (start, nbr, have_adj), built here if
    this is its first use)."""
    m = members.shape[0]
    sel, pa, pb, k = component_edge_steps(members, rpos, keep, edges_all, delta_all, rel, off0, off1, lines, xy_junction,
                                          index_min, index_max, fx, skip_max_steps, skip_tol)
    n_sel = sel.shape[0]
    empty = np.zeros(0, np.intp)
    if n_sel == 0:
        return False, 0, 0, empty, empty, start, nbr, have_adj
    n_changed = 0
    for e in range(n_sel):
        if k[e] != 1:
            n_changed += 1
    is_cut = np.zeros(n_sel, np.bool_)
    n_cut = 0
    if cut:
        if not have_adj:
            start, nbr = kept_adjacency(rel.shape[0], a_all, b_all, keep)
            have_adj = True
        d_i = np.empty(n_sel, np.int64)
        d_j = np.empty(n_sel, np.int64)
        for e in range(n_sel):
            d_i[e] = delta_all[sel[e], 0]
            d_j[e] = delta_all[sel[e], 1]
        lab_m = np.empty((m, 2), np.int64)
        ln_m = np.empty((m, 3))
        for p in range(m):
            i = members[p]
            lab_m[p, 0] = rel[i, 0] + off0
            lab_m[p, 1] = rel[i, 1] + off1
            ln_m[p, 0] = lines[i, 0]
            ln_m[p, 1] = lines[i, 1]
            ln_m[p, 2] = lines[i, 2]
        mis = edge_misfits(pa, pb, d_i, d_j, lab_m, ln_m, xy_junction, index_min, index_max, fx, skip_max_steps, cut_tol, members,
                           start, nbr, gpos)
        for e in range(n_sel):
            if mis[e] and k[e] == 1:
                is_cut[e] = True
                n_cut += 1
    if n_changed == 0 and n_cut == 0:
        return False, 0, 0, empty, empty, start, nbr, have_adj
    for e in range(n_sel):
        if k[e] != 1:
            delta_all[sel[e], 0] *= k[e]
            delta_all[sel[e], 1] *= k[e]
    n_s = n_sel - n_cut
    s_sel = np.empty(n_s, np.intp)
    s_a = np.empty(n_s, np.intp)
    s_b = np.empty(n_s, np.intp)
    s_d0 = np.empty(n_s, np.int64)
    s_d1 = np.empty(n_s, np.int64)
    c = 0
    for e in range(n_sel):
        if is_cut[e]:
            keep[sel[e]] = False
            continue
        s_sel[c] = sel[e]
        s_a[c] = pa[e]
        s_b[c] = pb[e]
        s_d0[c] = delta_all[sel[e], 0]
        s_d1[c] = delta_all[sel[e], 1]
        c += 1
    keep_s, _removed, sub_rel, sub_comp = clean_edges_walk(m, s_a, s_b, s_d0, s_d1, 2)
    for e in range(n_s):
        if not keep_s[e]:
            keep[s_sel[e]] = False
    for p in range(m):
        rel[members[p], 0] = sub_rel[p, 0]
        rel[members[p], 1] = sub_rel[p, 1]
    p_order, p_bounds = group_order(sub_comp)
    return True, n_changed, n_cut, p_order, p_bounds, start, nbr, have_adj


@njit
def _push(src, p_order, p_bounds, min_len, buf, top, w_start, w_len, w_rounds, w_g, w_may, n_w, rounds, may, component, next_id):
    """Push the pieces src[p_order[p_bounds[q]:p_bounds[q + 1]]] of at least min_len junctions on the work stack (in
    order: the last is popped first), each a new component id. Returns (n_w, top, next_id, junctions of the pieces
    dropped)."""
    dropped = 0
    for q in range(p_bounds.shape[0] - 1):
        nq = p_bounds[q + 1] - p_bounds[q]
        if nq < min_len:
            dropped += nq
            continue
        for h in range(nq):
            j = src[p_order[p_bounds[q] + h]]
            buf[top + h] = j
            component[j] = next_id
        next_id += 1
        w_start[n_w] = top
        w_len[n_w] = nq
        w_rounds[n_w] = rounds
        w_g[n_w] = -1
        w_may[n_w] = may
        n_w += 1
        top += nq
    return n_w, top, next_id, dropped


@njit
def _inlier_retry(members, rm, lm, xm, r_full, lim, off0, off1, xy_junction, blocks, B, index_min, index_max, fx, n_refs, band_px,
                  min_inside, cap2, R, t, z_min, z_max, noise_floor2, chi2, rms_ratio2, neighbour_noise, keep, a_all, b_all, start,
                  nbr, have_adj, gpos, stats):
    """`_choice_of`'s inlier retry (decision 0123): `_choose_offset` on the members with a finite residual ≤ lim, without
    a retry or a re-step (its stats counted in stats). Returns (accepted with the same offset, start, nbr, have_adj)."""
    m = members.shape[0]
    n_inl = 0
    for p in range(m):
        x = r_full[p]
        if math.isfinite(x) and x <= lim:
            n_inl += 1
    mi = np.empty(n_inl, np.intp)
    ri = np.empty((n_inl, 2), np.int64)
    li = np.empty((n_inl, 3))
    xi = np.empty((n_inl, 2))
    c = 0
    for p in range(m):
        x = r_full[p]
        if math.isfinite(x) and x <= lim:
            mi[c] = members[p]
            ri[c, 0] = rm[p, 0]
            ri[c, 1] = rm[p, 1]
            li[c, 0] = lm[p, 0]
            li[c, 1] = lm[p, 1]
            li[c, 2] = lm[p, 2]
            xi[c, 0] = xm[p, 0]
            xi[c, 1] = xm[p, 1]
            c += 1
    st, nf, ok, s1, s2, ne, ob, _r, _in = offset_choice_b(ri, li, xi, xy_junction, blocks, B, index_min, index_max, fx, n_refs, band_px,
                                                         min_inside, cap2, R, t, z_min, z_max)
    sub_ok = False
    if st != 0:
        if st >= 2:
            stats[S_OUT_OF_PATTERN] += 1
    else:
        stats[S_OUT_OF_DEPTH] += nf
        if ok:
            if _is_ambiguous(ne, s1, s2, noise_floor2, chi2, rms_ratio2):
                if neighbour_noise:
                    sigma2 = s1
                    if noise_floor2 > sigma2:
                        sigma2 = noise_floor2
                    if not (ne * (s2 - s1) / sigma2 < chi2):
                        if not have_adj:
                            start, nbr = kept_adjacency(gpos.shape[0], a_all, b_all, keep)
                            have_adj = True
                        if _shared_error(mi, ri, li, ob[0], ob[1], s1, s2, ne, xy_junction, index_min, index_max, fx, start, nbr, gpos,
                                         cap2, noise_floor2, chi2, rms_ratio2):
                            stats[S_NOISE_SPLIT] += 1
                            sub_ok = True
            else:
                sub_ok = True
    return sub_ok and ob[0] == off0 and ob[1] == off1, start, nbr, have_adj


@njit
def work_loop(order, bounds, g_status, g_fail, g_ok, g_s1, g_s2, g_neff, g_off, g_limit, g_r, g_in, g_written, g_bad, g_nbad,
              lone_rejected, has_lone, rel, lines, xy_cam, xy_junction, blocks, B, index_min, index_max, fx, n_refs, band_px,
              min_inside, cap2, R, t, z_min, z_max, keep, edges_all, delta_all, a_all, b_all, labels, residual, amb_best, amb_all,
              component, next_id, skip_tol, retry_limit, min_component, min_split, max_split_rounds, outlier_sigma, max_residual_px,
              noise_floor2, chi2, rms_ratio2, neighbour_noise, skip_edges_accepted, cut_misfit_edges, skip_max_steps, skip_tol_sigma,
              clusters_on, cluster_factor, cluster_floor_px, cluster_min, unlabelled):
    """labelling.label_epipolar's work loop (module doc) on the first round's results (`offset_choice_groups`' outputs,
    `_lone_arm_floor`'s lone_rejected when has_lone). rel, keep, delta_all (a copy of the observation's), labels, residual,
    amb_best, amb_all and component are updated in place. Returns (stats (N_STATS,) int64, left (6,) int64, next_id)."""
    M = labels.shape[0]
    E = edges_all.shape[0]
    stats = np.zeros(N_STATS, np.int64)
    left = np.zeros(6, np.int64)
    # runtime values, not literals: each helper is compiled once (a literal argument makes numba compile another version)
    yes = M >= 0
    no = M < 0
    zero = 0 * M
    # the kept edges' adjacency, built at first use (labelling._Graph)
    have_adj = no
    start = np.zeros(1, np.intp)
    nbr = np.zeros(0, np.intp)
    gpos = np.full(M, -1, np.intp)  # _Graph's work space
    cpos = np.full(M, -1, np.intp)  # the residual clusters' work space
    rpos = np.full(M, -1, np.intp)  # component_edge_steps' work space
    pos_of = np.full(M, -1, np.intp)  # the outliers' split
    restep_on = math.isfinite(skip_tol)
    cut_tol = outlier_sigma / skip_tol_sigma * skip_tol
    if max_residual_px > cut_tol:
        cut_tol = max_residual_px
    # the work stack: entry k is buf[w_start[k]:w_start[k] + w_len[k]], (rounds, first-round group or −1, may re-step)
    G = bounds.shape[0] - 1
    cap = M + G + 1
    buf = order.copy()
    w_start = np.empty(cap, np.intp)
    w_len = np.empty(cap, np.intp)
    w_rounds = np.empty(cap, np.int64)
    w_g = np.empty(cap, np.int64)
    w_may = np.empty(cap, np.bool_)
    n_w = 0
    for g in range(G):
        w_start[n_w] = bounds[g]
        w_len[n_w] = bounds[g + 1] - bounds[g]
        w_rounds[n_w] = 0
        w_g[n_w] = g
        w_may[n_w] = True
        n_w += 1
    top = order.shape[0]
    while n_w > 0:
        n_w -= 1
        s0 = w_start[n_w]
        m = w_len[n_w]
        rounds = w_rounds[n_w]
        g = w_g[n_w]
        may_restep = w_may[n_w]
        members = buf[s0 : s0 + m].copy()
        top = s0
        if rounds == 0 and m < min_component:
            left[L_TOO_SMALL] += m
            stats[S_TOO_SMALL] += 1
            continue
        if rounds > 0 and m < min_split:
            left[L_SPLIT_SMALL] += m
            continue
        restep = may_restep and restep_on
        if g >= 0 and has_lone and lone_rejected[g]:
            left[L_AMBIGUOUS] += m
            stats[S_AMBIGUOUS] += 1
            continue
        written = g >= 0 and g_written[g]
        if written and skip_edges_accepted and restep:
            # decision 0146: an accepted component's edges re-stepped under its offset (no cuts); if any changed, its labels
            # are taken back and its pieces labelled again
            did, n_ch, n_cut, p_order, p_bounds, start, nbr, have_adj = _restep(
                members, g_off[g, 0], g_off[g, 1], no, rpos, keep, edges_all, delta_all, rel, lines, xy_junction, index_min,
                index_max, fx, skip_max_steps, skip_tol, cut_tol, a_all, b_all, start, nbr, have_adj, gpos)
            if did:
                stats[S_EDGES_RESTEPPED] += n_ch
                stats[S_COMPONENTS_RESTEPPED] += 1
                stats[S_RESTEPPED_ACCEPTED] += 1
                for p in range(m):
                    labels[members[p], 0] = unlabelled
                    labels[members[p], 1] = unlabelled
                    residual[members[p]] = np.nan
                n_w, top, next_id, _d = _push(members, p_order, p_bounds, zero, buf, top, w_start, w_len, w_rounds, w_g, w_may, n_w,
                                              rounds, no, component, next_id)
                continue
        if written:
            stats[S_OUT_OF_DEPTH] += g_fail[g]
            stats[S_LABELLED] += 1
            n_bad = g_nbad[g]
            b0 = bounds[g]
            bad = g_bad[b0 : b0 + m]
            inside_m = g_in[b0 : b0 + m]
        else:
            # the choice (labelling._choice_of)
            reason = -1  # −1: accepted; else an L_* index
            has_limit = False
            limit = 0.0
            rm, lm, xm = gather_members(members, rel, lines, xy_cam)
            if g >= 0:
                b0 = bounds[g]
                st = g_status[g]
                nf = g_fail[g]
                ok = g_ok[g]
                s1 = g_s1[g]
                s2 = g_s2[g]
                ne = g_neff[g]
                off0 = g_off[g, 0]
                off1 = g_off[g, 1]
                r_full = g_r[b0 : b0 + m]
                inside = g_in[b0 : b0 + m]
                has_limit = True
                limit = g_limit[g]
            else:
                st, nf, ok, s1, s2, ne, ob, r_full, inside = offset_choice_b(rm, lm, xm, xy_junction, blocks, B, index_min, index_max, fx,
                                                                              n_refs, band_px, min_inside, cap2, R, t, z_min, z_max)
                off0 = ob[0]
                off1 = ob[1]
            lim_choice = 0.0
            has_lim_choice = False
            if st != 0:
                if st >= 2:
                    stats[S_OUT_OF_PATTERN] += 1
                reason = L_NO_OFFSET
            else:
                stats[S_OUT_OF_DEPTH] += nf
                if not ok:
                    reason = L_NO_OFFSET
                elif _is_ambiguous(ne, s1, s2, noise_floor2, chi2, rms_ratio2):
                    shared = False
                    if neighbour_noise:
                        sigma2 = s1
                        if noise_floor2 > sigma2:
                            sigma2 = noise_floor2
                        if not (ne * (s2 - s1) / sigma2 < chi2):
                            if not have_adj:
                                start, nbr = kept_adjacency(M, a_all, b_all, keep)
                                have_adj = True
                            shared = _shared_error(members, rm, lm, off0, off1, s1, s2, ne, xy_junction, index_min, index_max, fx,
                                                   start, nbr, gpos, cap2, noise_floor2, chi2, rms_ratio2)
                    if shared:
                        stats[S_NOISE_SPLIT] += 1
                    else:
                        if restep:
                            # decision 0125: the edges re-stepped under the best offset, with decision 0130's cuts
                            did, n_ch, n_cut, p_order, p_bounds, start, nbr, have_adj = _restep(
                                members, off0, off1, cut_misfit_edges, rpos, keep, edges_all, delta_all, rel, lines, xy_junction,
                                index_min, index_max, fx, skip_max_steps, skip_tol, cut_tol, a_all, b_all, start, nbr, have_adj, gpos)
                            if did:
                                stats[S_EDGES_RESTEPPED] += n_ch
                                stats[S_EDGES_CUT] += n_cut
                                stats[S_COMPONENTS_RESTEPPED] += 1
                                n_w, top, next_id, dropped = _push(members, p_order, p_bounds, min_split if n_cut > 0 else zero, buf, top,
                                                                   w_start, w_len, w_rounds, w_g, w_may, n_w, rounds, no, component,
                                                                   next_id)
                                left[L_SPLIT_SMALL] += dropped
                                continue
                        # decision 0123: the best offset judged on its inliers
                        lim = limit if has_limit else _outlier_limit(r_full, outlier_sigma, max_residual_px)
                        if retry_limit < lim:
                            lim = retry_limit
                        n_inl = 0
                        for p in range(m):
                            x = r_full[p]
                            if math.isfinite(x) and x <= lim:
                                n_inl += 1
                        if n_inl == m or n_inl < min_split:
                            reason = L_AMBIGUOUS
                        else:
                            same, start, nbr, have_adj = _inlier_retry(
                                members, rm, lm, xm, r_full, lim, off0, off1, xy_junction, blocks, B, index_min, index_max, fx, n_refs,
                                band_px, min_inside, cap2, R, t, z_min, z_max, noise_floor2, chi2, rms_ratio2, neighbour_noise, keep,
                                a_all, b_all, start, nbr, have_adj, gpos, stats)
                            if same:
                                lim_choice = lim
                                has_lim_choice = True
                            else:
                                reason = L_AMBIGUOUS
            if reason == L_AMBIGUOUS:
                left[L_AMBIGUOUS] += m
                stats[S_AMBIGUOUS] += 1
                for p in range(m):
                    i = members[p]
                    amb_all[i, 0] = rm[p, 0] + off0
                    amb_all[i, 1] = rm[p, 1] + off1
                    if m >= min_split:
                        amb_best[i, 0] = rm[p, 0] + off0
                        amb_best[i, 1] = rm[p, 1] + off1
                continue
            if reason >= 0:
                left[reason] += m
                continue
            if has_lim_choice:
                if has_limit:
                    if lim_choice < limit:
                        limit = lim_choice
                else:
                    limit = lim_choice
                    has_limit = True
            wl = limit if has_limit else _outlier_limit(r_full, outlier_sigma, max_residual_px)
            lab = np.empty((m, 2), np.int64)
            for p in range(m):
                lab[p, 0] = rm[p, 0] + off0
                lab[p, 1] = rm[p, 1] + off1
            bad, n_bad = write_component(members, lab, r_full, inside, wl, labels, residual)
            inside_m = inside
            stats[S_LABELLED] += 1
        if clusters_on and m >= 2 * cluster_min:
            if not have_adj:
                start, nbr = kept_adjacency(M, a_all, b_all, keep)
                have_adj = True
            out, added = elevated_pieces(members, residual, bad, start, nbr, cpos, cluster_factor, cluster_floor_px, cluster_min)
            if added != 0:
                for p in range(m):
                    if out[p] and not bad[p]:
                        labels[members[p], 0] = unlabelled
                        labels[members[p], 1] = unlabelled
                        residual[members[p]] = np.nan
                stats[S_CLUSTERS] += added
                bad = out
                n_bad = n_bad + added
        if n_bad == 0:
            continue
        # outliers: their edges to the inliers cut; what they hold together labelled again on its own
        if rounds >= max_split_rounds:
            for p in range(m):
                if bad[p]:
                    if inside_m[p]:
                        left[L_RESIDUAL] += 1
                    else:
                        left[L_DEPTH] += 1
            continue
        stats[S_SPLIT] += 1
        n_o = 0
        for p in range(m):
            if bad[p]:
                n_o += 1
        outl = np.empty(n_o, np.intp)
        c = 0
        for p in range(m):
            if bad[p]:
                outl[c] = members[p]
                c += 1
        outl = np.sort(outl)
        for p in range(n_o):
            pos_of[outl[p]] = p
        n_e = 0
        for e in range(E):
            if keep[e] and pos_of[edges_all[e, 0]] >= 0 and pos_of[edges_all[e, 1]] >= 0:
                n_e += 1
        sa = np.empty(n_e, np.intp)
        sb = np.empty(n_e, np.intp)
        sd0 = np.empty(n_e, np.int64)
        sd1 = np.empty(n_e, np.int64)
        c = 0
        for e in range(E):
            if keep[e] and pos_of[edges_all[e, 0]] >= 0 and pos_of[edges_all[e, 1]] >= 0:
                sa[c] = pos_of[edges_all[e, 0]]
                sb[c] = pos_of[edges_all[e, 1]]
                sd0[c] = delta_all[e, 0]
                sd1[c] = delta_all[e, 1]
                c += 1
        for p in range(n_o):
            pos_of[outl[p]] = -1
        sub_rel, sub_comp = propagate(n_o, sa, sb, sd0, sd1, np.ones(n_e, np.bool_))
        for p in range(n_o):
            rel[outl[p], 0] = sub_rel[p, 0]
            rel[outl[p], 1] = sub_rel[p, 1]
        p_order, p_bounds = group_order(sub_comp)
        n_w, top, next_id, _d = _push(outl, p_order, p_bounds, zero, buf, top, w_start, w_len, w_rounds, w_g, w_may, n_w, rounds + 1, yes,
                                      component, next_id)
    return stats, left, next_id
