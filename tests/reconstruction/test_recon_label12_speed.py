"""Decision 0127 (label stage, round twelve): the new code paths equal the ones they replace."""

import numpy as np

from reconstruction import crossing_fill as CF


def _u64_cases(rng):
    """Unsigned arrays of every shape the bucket sort treats apart: empty, one value, all equal, duplicates,
    values spread over all 64 bits, dense clusters (one bucket holding most values), small ranges."""
    yield np.zeros(0, np.uint64)
    yield np.array([7], np.uint64)
    yield np.array([5, 5], np.uint64)
    yield np.array([2**64 - 1, 0, 2**63], np.uint64)
    yield np.full(100, 3, np.uint64)
    for trial in range(40):
        n = int(rng.integers(2, 5000))
        kind = trial % 5
        if kind == 0:
            v = rng.integers(0, 2**63, n, dtype=np.uint64) * np.uint64(2) + rng.integers(0, 2, n, dtype=np.uint64)
        elif kind == 1:
            v = rng.integers(0, 50, n).astype(np.uint64)  # many equal values
        elif kind == 2:
            # most values in a narrow cluster, a few far away: one bucket takes the cluster
            v = rng.integers(10**12, 10**12 + 1000, n).astype(np.uint64)
            v[rng.integers(0, n, 3)] = np.uint64(2**62)
        elif kind == 3:
            v = np.sort(rng.integers(0, 2**40, n).astype(np.uint64))[::-1].copy()  # reversed
        else:
            v = np.repeat(rng.integers(0, 2**50, max(n // 7, 1)).astype(np.uint64), 7)[:n]
            rng.shuffle(v)
        yield v


def test_bucket_sort_equals_numpy_sort():
    rng = np.random.default_rng(127)
    n_cases = 0
    for v in _u64_cases(rng):
        got = CF._k_sort_u64(v)
        assert got.dtype == np.uint64
        assert np.array_equal(got, np.sort(v))
        n_cases += 1
    assert n_cases >= 45


def _old_sorted_with_keys(sel, key):
    """`crossing_fill._sorted_with_keys` before decision 0127: `_k_pack`, NumPy's sort, `_k_unpack_keys`."""
    n = len(key)
    if n >= 2:
        b = int(n - 1).bit_length()
        packed, ok = CF._k_pack(key, b)
        if ok:
            order, ok, key_sorted = CF._k_unpack_keys(np.sort(packed), sel, key, b)
            if ok:
                return order, key_sorted
    o = np.argsort(key)
    return sel[o], key[o]


def test_sorted_with_keys_equals_the_numpy_sort_path():
    """Keys like `_k_order`'s (line code · span + position), distinct, a few ulp apart, tied, and not positive:
    the same order and keys as before, and the fast path taken where it can be."""
    rng = np.random.default_rng(1270)
    fast = 0
    for trial in range(80):
        n = int(rng.integers(0, 30000 if trial % 10 == 0 else 3000))
        lines = rng.integers(0, 120, n)
        span = 2.0 * (1300.0 + 1.0)
        key = (lines + 130.0) * span + rng.uniform(-1300.0, 1300.0, n)
        if trial % 4 == 1 and n > 2:
            key[rng.integers(0, n, 3)] = key[0]  # exact ties: the argsort decides
        if trial % 4 == 2 and n > 2:
            key[1] = np.nextafter(key[0], np.inf)  # neighbours within the packed bits
        if trial % 8 == 3 and n > 2:
            key[2] = -1.0  # not positive: the argsort
        sel = rng.permutation(n + 5)[:n].astype(np.intp)
        o_old, k_old = _old_sorted_with_keys(sel, key)
        o_new, k_new = CF._sorted_with_keys(sel, key)
        assert np.array_equal(o_new, o_old)
        assert np.array_equal(k_new, k_old)
        assert np.array_equal(o_new, sel[np.argsort(key)]) or trial % 4 == 1
        if n >= 2:
            fast += bool(CF._k_sorted_keys(sel, key, int(n - 1).bit_length())[1])
    assert fast >= 30


def _old_restep_steps(members, M, keep, edges_all, delta_all, rel, off, lines, xy_junction, index_min, index_max, fx, k_max, tol):
    """`label_epipolar`'s `_restep` before decision 0127, up to `edge_steps` (NumPy gathers)."""
    from reconstruction import _ambiguity_kernels as AK

    pos_m = np.full(M, -1, np.intp)
    pos_m[members] = np.arange(len(members))
    sel = np.flatnonzero(keep & (pos_m[edges_all[:, 0]] >= 0) & (pos_m[edges_all[:, 1]] >= 0))
    if len(sel) == 0:
        return sel, np.zeros((0, 2), np.intp), None
    sub_e = pos_m[edges_all[sel]]
    k = AK.edge_steps(np.ascontiguousarray(sub_e[:, 0]), np.ascontiguousarray(sub_e[:, 1]),
                      np.ascontiguousarray(delta_all[sel, 0]), np.ascontiguousarray(delta_all[sel, 1]),
                      np.ascontiguousarray(rel[members] + np.asarray(off, np.int64)), np.ascontiguousarray(lines[members]),
                      xy_junction, index_min, index_max, fx, k_max, tol)
    return sel, sub_e, k


def test_component_edge_steps_equals_the_numpy_gathers():
    """`_ambiguity_kernels.component_edge_steps` against the former NumPy code of `_restep` on random graphs: the same
    edges, the same end positions and the same steps, some of them other than 1; pos left all −1."""
    from reconstruction import _ambiguity_kernels as AK

    rng = np.random.default_rng(1271)
    L, index_min = 41, -20
    g = np.arange(L) + index_min
    # a pattern's junctions in normalised projector coordinates (slopes 0.3 and −1.2, pitch 0.02)
    n1, n2, p = 0.3, -1.2, 0.02
    I, J = np.meshgrid(g, g, indexing="ij")
    xy_junction = np.ascontiguousarray(np.stack([(I - J) * p / (n2 - n1), (n2 * I - n1 * J) * p / (n2 - n1)], axis=-1))
    changed = 0
    for trial in range(60):
        M = int(rng.integers(2, 300))
        E = int(rng.integers(0, 3 * M))
        edges = rng.integers(0, M, (E, 2)).astype(np.int64)
        delta = rng.choice(np.array([[1, 0], [0, 1], [-1, 0], [0, -1], [1, 1]]), E).astype(np.int64)
        keep = rng.random(E) < 0.8
        rel = rng.integers(-15, 15, (M, 2)).astype(np.int64)
        # epipolar lines through each member's junction (some a line off: the steps change)
        lab = np.clip(rel, index_min, index_min + L - 1)
        pt = xy_junction[lab[:, 0] - index_min, lab[:, 1] - index_min]
        ang = rng.uniform(0, np.pi, M)
        lines = np.stack([np.sin(ang), -np.cos(ang), -(np.sin(ang) * pt[:, 0] - np.cos(ang) * pt[:, 1])], axis=1)
        lines[:, 2] += rng.normal(0, 1e-4, M)
        members = np.sort(rng.permutation(M)[: int(rng.integers(0, M + 1))]).astype(np.intp)
        off = rng.integers(-3, 4, 2).astype(np.int64)
        args = (xy_junction, index_min, index_min + L - 1, 1000.0, 6, float(rng.choice([0.05, 0.5, 3.0])))
        sel0, sub0, k0 = _old_restep_steps(members, M, keep, edges, delta, rel, off, lines, *args)
        pos = np.full(M, -1, np.intp)
        sel1, pa, pb, k1 = AK.component_edge_steps(members, pos, keep, edges, delta, rel, int(off[0]), int(off[1]), lines, *args)
        assert (pos == -1).all()
        assert np.array_equal(sel0, sel1)
        assert np.array_equal(sub0[:, 0], pa) and np.array_equal(sub0[:, 1], pb)
        if k0 is None:
            assert len(k1) == 0
        else:
            assert np.array_equal(k0, k1)
            changed += int((k1 != 1).sum())
    assert changed > 0


def test_choose_offset_block_path_equals_offset_choice():
    """`_choose_offset` now scores by blocks (`offset_choice_b` on `labelling._junction_blocks`): every output equal to
    `offset_choice`'s (the former path) on random components of two pattern sizes, with missing pattern junctions;
    accepted, no-admissible and out-of-depth outcomes all occur; the blocks are kept per table and rebuilt for another."""
    from reconstruction import _label_kernels as K
    from reconstruction import labelling as LB

    rng = np.random.default_rng(1272)
    outcomes = set()
    for L in (41, 81):
        imin = -(L // 2)
        imax = imin + L - 1
        ii, jj = np.meshgrid(np.arange(L), np.arange(L), indexing="ij")
        s = 1.0 / L
        xy = np.ascontiguousarray(np.stack([s * (ii - jj) + 1e-3 * s * rng.normal(size=ii.shape),
                                            1.5 * s * (ii + jj) - 1.5 + 1e-3 * s * rng.normal(size=ii.shape)], axis=-1))
        xy[2, 3] = np.nan
        xy[8:16, 16:24] = np.nan
        blocks = LB._junction_blocks(xy)
        assert LB._junction_blocks(xy) is blocks
        np.testing.assert_array_equal(blocks, K.junction_blocks(xy, K._BLOCK))
        R = np.eye(3)
        t = np.array([100.0, 0.0, 0.0])
        for trial in range(40):
            m = int(rng.choice([1, 3, 20, 150, 500]))
            spread = L if trial % 5 == 4 else 8  # wider than the pattern: no admissible offset
            rel = rng.integers(-spread, spread + 1, (m, 2)).astype(np.int64)
            true = rel + rng.integers(-3, 4, 2)
            p = xy[np.clip(true[:, 0] - imin, 0, L - 1), np.clip(true[:, 1] - imin, 0, L - 1)]
            p = np.where(np.isfinite(p), p, 0.0)
            ang = rng.uniform(0, np.pi, m)
            ln = np.column_stack([np.sin(ang), -np.cos(ang), -(np.sin(ang) * p[:, 0] - np.cos(ang) * p[:, 1])])
            ln[:, 2] += rng.normal(0, 2e-4, m)
            ln = np.ascontiguousarray(ln)
            xy_cam = np.ascontiguousarray(rng.normal(0, 0.2, (m, 2)))
            z_max = float(rng.choice([1e6, 50.0]))
            args = (imin, imax, 800.0, 5, 4.0, 0.9, 1.0, R, t, 1.0, z_max)
            ref = K.offset_choice(rel, ln, xy_cam, xy, *args)
            got = K.offset_choice_b(rel, ln, xy_cam, xy, LB._junction_blocks(xy), K._BLOCK, *args)
            assert len(ref) == len(got)
            for x, y in zip(ref, got):
                if isinstance(x, np.ndarray):
                    assert x.dtype == y.dtype
                    np.testing.assert_array_equal(x, y)
                else:
                    assert x == y or (x != x and y != y)
            outcomes.add("status" if ref[0] != 0 else ("ok" if ref[2] else "depth"))
    assert outcomes == {"status", "ok", "depth"}
