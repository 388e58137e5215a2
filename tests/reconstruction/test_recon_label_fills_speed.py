"""Decision 0158: exact speed changes of `labelling.label_epipolar` and the crossing fills. Each new path must equal
the one it replaces, recomputed, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction import _label_kernels as K


def _graph(rng, n, e, n_bad):
    """A random junction graph: edges a → b with the steps of true labels, n_bad of them given a wrong step (the
    contradictions `clean_edges` drops), a few duplicate and self-consistent parallel edges."""
    lab = rng.integers(-20, 20, size=(n, 2))
    a = rng.integers(0, n, size=e)
    b = rng.integers(0, n, size=e)
    d = lab[b] - lab[a]
    bad = rng.choice(e, size=min(n_bad, e), replace=False) if e else np.zeros(0, np.intp)
    d[bad] += rng.integers(1, 3, size=(len(bad), 2))
    return a.astype(np.intp), b.astype(np.intp), np.ascontiguousarray(d[:, 0], np.int64), np.ascontiguousarray(d[:, 1], np.int64)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("rounds", [0, 1, 2, 3])
def test_clean_edges_walk_is_clean_edges_then_propagate(seed, rounds):
    """`clean_edges_walk` = `clean_edges` followed by `propagate` on its keep: keep, removed, rel, comp, on graphs
    without contradictions (the first round's walk is returned), with a few (the second round's) and with many
    (edges dropped in the last round: walked again)."""
    rng = np.random.default_rng(seed)
    seen_reuse = seen_walk = False
    for n, e, n_bad in [(1, 0, 0), (5, 0, 0), (60, 90, 0), (60, 90, 1), (200, 400, 3), (200, 400, 40), (30, 200, 60), (400, 300, 0)]:
        a, b, d0, d1 = _graph(rng, n, e, n_bad)
        keep_r, removed_r = K.clean_edges(n, a, b, d0, d1, rounds)
        rel_r, comp_r = K.propagate(n, a, b, d0, d1, keep_r)
        keep, removed, rel, comp = K.clean_edges_walk(n, a, b, d0, d1, rounds)
        assert np.array_equal(keep, keep_r) and removed == removed_r
        assert rel.dtype == rel_r.dtype and comp.dtype == comp_r.dtype
        assert np.array_equal(rel, rel_r) and np.array_equal(comp, comp_r)
        seen_reuse |= rounds > 0 and e > 0 and removed == 0
        seen_walk |= removed > 0
    if rounds > 0:
        assert seen_reuse and seen_walk
