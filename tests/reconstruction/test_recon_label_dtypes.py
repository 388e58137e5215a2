"""Decision 0150: label_samples keeps its per-sample arrays narrow while the steps run (families int8, index float32,
seed and seed_jid int32, each sample's trace position int32): every value they hold is a small integer (or NaN), so
the narrow types hold them exactly and the steps' scattered reads touch a quarter to a half of the memory. The
results must be those of the wide types (intp families, float64 index, int64 seeds and junctions, intp positions):
here the label stage runs on a simulated frame (unseen seed 185) with the wide arrays put back in place of the narrow
ones, and everything it returns is compared to the bit. label_samples still returns index as float64 and the
junctions as int64."""

from __future__ import annotations

from dataclasses import replace

import numpy as np


def _wide(frame):
    """The frame with each sample's trace position as intp (built again, not converted)."""
    tp = frame.prep.traces
    pos_of = np.full(len(tp.pos_of), -1, np.intp)
    pos_of[tp.sid] = np.arange(len(tp.sid))
    prep = replace(frame.prep, traces=replace(tp, pos_of=pos_of))
    return replace(frame, prep=prep)


def test_narrow_arrays_give_the_wide_arrays_results(monkeypatch):
    from reconstruction import _label_kernels as K
    from reconstruction.pipeline import finish_frame
    from tests.reconstruction._scenes import unseen_frame

    procam, pattern, truth, o, frame = unseen_frame(185)
    assert frame.prep.traces is not None and frame.prep.traces.pos_of.dtype == np.int32
    narrow = finish_frame(frame)
    seen = {}
    orig_arrays = K.label_arrays

    def label_arrays(q, family, unlabelled):
        # the arrays as they were before decision 0150 (NumPy, wide types), not converted from the narrow ones
        fam, index, q_out, seed_jid, seed = orig_arrays(q, family, unlabelled)
        seen["narrow"] = (fam.dtype, index.dtype, seed_jid.dtype, seed.dtype)
        P = len(q)
        return (np.asarray(family).astype(np.intp), np.full(P, np.nan), np.array(q, np.float64), np.full(P, -1, np.int64),
                np.full(P, unlabelled, np.int64))

    monkeypatch.setattr(K, "label_arrays", label_arrays)
    def positions_of(P, sid):
        pos_of = np.full(P, -1, np.intp)
        pos_of[sid] = np.arange(len(sid))
        return pos_of

    monkeypatch.setattr(K, "positions_of", positions_of)
    wide = finish_frame(_wide(frame))
    assert seen["narrow"] == (np.dtype(np.int8), np.dtype(np.float32), np.dtype(np.int32), np.dtype(np.int32))
    assert narrow.n_points > 10000 and narrow.n_points == wide.n_points
    for name in ("points_proj", "q_cam", "junction_labels"):
        a, b = getattr(narrow, name), getattr(wide, name)
        assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), name
    sa = {k: v for k, v in narrow.stats.items() if k != "ms"}
    sb = {k: v for k, v in wide.stats.items() if k != "ms"}
    assert sa == sb


def test_label_samples_returns_wide_types():
    """The returned index is float64 and the junctions int64 (the stages after read them as before), and every
    finite index is an integer: the premise that float32 holds it exactly."""
    from reconstruction.pipeline import finish_frame
    from reconstruction import labelling as L
    from tests.reconstruction._scenes import unseen_frame

    procam, pattern, truth, o, frame = unseen_frame(185)
    got = {}
    orig = L.label_samples

    def spy(*a, **kw):
        got["sl"] = orig(*a, **kw)
        return got["sl"]

    import reconstruction.pipeline as P

    P.label_samples = spy
    try:
        finish_frame(frame)
    finally:
        P.label_samples = orig
    sl = got["sl"]
    assert sl.index.dtype == np.float64 and sl.junction.dtype == np.int64
    fin = np.isfinite(sl.index)
    assert fin.sum() > 10000 and np.array_equal(sl.index[fin], np.round(sl.index[fin]))
    assert (np.abs(sl.index[fin]) < 2**24).all()
    assert (sl.junction[~fin] == -1).all() and (sl.junction[fin] >= 0).any()
