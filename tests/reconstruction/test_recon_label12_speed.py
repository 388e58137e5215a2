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
