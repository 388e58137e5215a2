"""Decision 0146: a junction's seeds on a trace piece of another surface (off the seeds' ridge brightness) are
taken back before the seeds spread.

- The check on a synthetic frame: junction 0's family-1 seeds lie on pieces at ridge brightness 100, 100, 40 and
  88; the seeds on the 40 piece are taken back (seed and seed_jid), those within 25 % are kept; another junction's
  seeds, and the other family's, are judged against their own group only; unseeded samples are not read.
- Unseen seed 185 (the scene where it was found, `benchmarks.unseen.draw_scene`): junctions at a silhouette seeded
  pieces of the dim surface beside it (ridge ~47 against ~127), 6 j-lines off, and the limb step 9e copied them to
  the neighbouring lines (0.30 % of the points more than 1 % off, 156). With the check at most half as many (the
  test can fail: without the check, or with the share 0.25).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from reconstruction.rigmodel import UNLABELLED
from reconstruction.seed_brightness import drop_seeds_off_brightness


def test_seeds_on_a_piece_off_the_junction_brightness_are_taken_back():
    # pieces 0..5 of 6 samples each, in trace order; sample ids shuffled against positions
    piece = np.repeat(np.arange(6), 6).astype(np.intp)
    n = len(piece)
    sid = np.random.default_rng(0).permutation(n).astype(np.intp)
    fam = np.ones(n, np.intp)
    fam[sid[piece == 5]] = 2
    ridge = np.empty(n, np.float32)
    bright = [100.0, 100.0, 40.0, 88.0, 30.0, 60.0]
    for p in range(6):
        ridge[sid[piece == p]] = bright[p]
    ridge[sid[piece == 1][5]] = 10.0  # an unseeded sample of piece 1: the seeds' median, not the piece's, is read
    seed = np.full(n, UNLABELLED, np.int64)
    seed_jid = np.full(n, -1, np.int64)
    # (junction, index, seeds on the piece): junction 0's family-1 seeds at 100 (7), 40 (3) and 88 (2): median 100;
    # junction 1's alone at 30; junction 0's family-2 seeds at 60, judged against family 2 only
    for p, (jid, k, cnt) in enumerate([(0, 5, 4), (0, 5, 3), (0, 5, 3), (0, 5, 2), (1, 9, 3), (0, 7, 3)]):
        s = sid[piece == p][:cnt]
        seed[s] = k
        seed_jid[s] = jid
    before, before_jid = seed.copy(), seed_jid.copy()
    got = drop_seeds_off_brightness(sid, piece, fam, seed, seed_jid, ridge, 0.25, UNLABELLED)
    off = sid[piece == 2][:3]
    assert got == 3
    assert (seed[off] == UNLABELLED).all() and (seed_jid[off] == -1).all()
    keep = np.setdiff1d(np.flatnonzero(before != UNLABELLED), off)
    assert (seed[keep] == before[keep]).all() and (seed_jid[keep] == before_jid[keep]).all()
    assert (seed[before == UNLABELLED] == UNLABELLED).all()
    assert drop_seeds_off_brightness(sid, piece, fam, seed, seed_jid, ridge, 0.25, UNLABELLED) == 0  # nothing left
    # the families pooled (all family 1), junction 0's median is 88 and the piece at 60 is off too: they are not pooled
    seed2, jid2 = before.copy(), before_jid.copy()
    assert drop_seeds_off_brightness(sid, piece, np.ones(n, np.intp), seed2, jid2, ridge, 0.25, UNLABELLED) == 6
    # a larger share: nothing taken back
    seed2, jid2 = before.copy(), before_jid.copy()
    assert drop_seeds_off_brightness(sid, piece, fam, seed2, jid2, ridge, 0.7, UNLABELLED) == 0


def test_seed_185_seeds_across_a_silhouette_taken_back():
    """Against simulated truth: with the check at most half as many points are more than 1 % off (measured 156 →
    10 with the share 0.2; 0.25 leaves 129: a 3-sample piece across the silhouette), for at most 2 % of the
    points."""
    from benchmarks._common import relative_errors
    from reconstruction.pipeline import finish_frame
    from tests.reconstruction._scenes import unseen_frame

    procam, pattern, truth, o, frame = unseen_frame(185)
    out = {}
    for on in (True, False):
        res = finish_frame(replace(frame, options=replace(o, trace=replace(o.trace, seed_brightness=on))))
        rel = relative_errors(res.points_proj, res.q_cam, truth)
        out[on] = (float((rel > 0.01).mean()), res.n_points, res.stats.get("seeds_off_brightness", 0))
    assert out[True][0] <= 0.5 * out[False][0] and out[False][0] > 0.002
    assert out[True][2] > 0 and out[False][2] == 0
    assert out[True][1] >= 0.98 * out[False][1]


def _random_frame(rng, n_pieces, p_seed):
    """Trace order over a random subset of P samples: pieces as runs, seeds of a few junctions each, random
    ridge brightness with ties (rounded), both families."""
    P = int(rng.integers(50, 3000))
    sizes = rng.integers(1, 30, n_pieces)
    n = min(int(sizes.sum()), P)
    sid = rng.permutation(P)[:n].astype(np.intp)
    piece = np.repeat(np.arange(n_pieces), sizes)[:n].astype(np.intp)
    fam = rng.integers(1, 3, P).astype(np.intp)
    seed = np.where(rng.random(P) < p_seed, rng.integers(-20, 20, P), UNLABELLED).astype(np.intp)
    seed_jid = np.where(seed != UNLABELLED, rng.integers(-1, max(2, n_pieces // 3), P), -1).astype(np.intp)
    ridge = np.round(rng.uniform(20, 200, P) / 5) * 5
    return sid, piece, fam, seed, seed_jid, ridge.astype(np.float32)


def test_compiled_pass_equals_the_reference_version():
    """The single-pass kernel takes back exactly the seeds the first version did (same count, same arrays), on
    random frames with ties, empty pieces, unlabelled seeds with a junction and seeds without one."""
    from tests.reconstruction._seed_brightness_reference import drop_seeds_off_brightness as reference

    rng = np.random.default_rng(146)
    dropped = 0
    for trial in range(60):
        frame = _random_frame(rng, int(rng.integers(1, 400)), float(rng.uniform(0.05, 0.9)))
        share = float(rng.choice([0.1, 0.2, 0.25, 0.5]))
        a = [x.copy() for x in frame]
        b = [x.copy() for x in frame]
        got = drop_seeds_off_brightness(*a[:6], share, UNLABELLED)
        want = reference(*b[:6], share, UNLABELLED)
        assert got == want, trial
        assert np.array_equal(a[3], b[3]) and np.array_equal(a[4], b[4]), trial
        dropped += got
    assert dropped > 100  # the frames do exercise the take-back


def _runs_frame(rng):
    """Trace order as label_samples sees it: pieces as runs, each junction's seeds on a piece one run of positions
    (the samples near the junction) at either end of the piece, a few junctions' lines also in two runs of one
    piece, seeds with no junction, ridge brightness with ties and a piece now and then on a dimmer surface."""
    n_pieces = int(rng.integers(1, 300))
    sizes = rng.integers(1, 25, n_pieces)
    n = int(sizes.sum())
    P = n + int(rng.integers(0, 200))
    sid = rng.permutation(P)[:n].astype(np.intp)
    piece = np.repeat(np.arange(n_pieces), sizes).astype(np.intp)
    fam = rng.integers(1, 3, P).astype(np.intp)
    seed = np.full(P, UNLABELLED, np.intp)
    seed_jid = np.full(P, -1, np.intp)
    ridge = np.round(rng.uniform(80, 120, P) / 5) * 5
    n_j = max(2, n_pieces // 2)
    a = 0
    for p, m in enumerate(sizes.tolist()):
        if rng.random() < 0.3:
            ridge[sid[a : a + m]] *= 0.4  # another surface
        for lo, hi in ((0, int(rng.integers(0, m + 1))), (int(rng.integers(0, m + 1)), m)):
            s = sid[a + lo : a + hi]
            seed[s] = int(rng.integers(-20, 20))
            seed_jid[s] = int(rng.integers(-1, n_j))
        if m > 4 and rng.random() < 0.2:  # one junction line in two runs of the piece
            seed[sid[a]] = seed[sid[a + m - 1]] = 3
            seed_jid[sid[a]] = seed_jid[sid[a + m - 1]] = int(rng.integers(0, n_j))
        a += m
    return sid, piece, fam, seed, seed_jid, ridge.astype(np.float32)


def test_spread_with_the_check_equals_the_check_then_the_spread():
    """Decision 0150: `spread_checked_seeds` (the check and the spreading in one pass over the positions) gives what
    the kept first version of the check (`_seed_brightness_reference`) followed by `_label_kernels.spread_seeds` gives:
    the seeds taken back, index, seed_jid, the positions reached and the counts, with the check on and off, on
    random frames (any grouping) and on frames laid out as label_samples' (a junction line one run of a piece)."""
    from reconstruction import _label_kernels as K
    from reconstruction.seed_brightness import spread_checked_seeds
    from tests.reconstruction._seed_brightness_reference import drop_seeds_off_brightness as reference

    rng = np.random.default_rng(150)
    dropped = 0
    for trial in range(160):
        if trial % 2:
            sid, piece, fam, seed, seed_jid, ridge = _random_frame(rng, int(rng.integers(1, 400)), float(rng.uniform(0.05, 0.9)))
        else:
            sid, piece, fam, seed, seed_jid, ridge = _runs_frame(rng)
        ts = rng.uniform(0, 3, len(sid)).cumsum()
        share = float(rng.choice([0.1, 0.2, 0.25, 0.5]))
        for check in (True, False):
            s0, j0, i0 = seed.copy(), seed_jid.copy(), np.full(len(seed), np.nan)
            want_d = reference(sid, piece, fam, s0, j0, ridge, share, UNLABELLED) if check else 0
            want_got, want_seeded, want_conf = K.spread_seeds(sid, piece, ts, s0, j0, i0, UNLABELLED)
            s1, j1, i1 = seed.copy(), seed_jid.copy(), np.full(len(seed), np.nan)
            got, seeded, conf, d = spread_checked_seeds(sid, piece, ts, fam, s1, j1, i1, ridge, share, check, UNLABELLED)
            assert d == want_d and seeded == want_seeded and conf == want_conf, (trial, check)
            assert np.array_equal(got, want_got) and np.array_equal(s1, s0) and np.array_equal(j1, j0), (trial, check)
            assert np.array_equal(i1, i0, equal_nan=True), (trial, check)
            dropped += d
    assert dropped > 200  # the frames do exercise the take-back
