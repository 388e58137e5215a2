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
    """The frame with its trace positions as intp, and label_arrays patched to give the wide arrays."""
    tp = frame.prep.traces
    prep = replace(frame.prep, traces=replace(tp, pos_of=tp.pos_of.astype(np.intp)))
    return replace(frame, prep=prep)


def test_narrow_arrays_give_the_wide_arrays_results(monkeypatch):
    from reconstruction import _label_kernels as K
    from reconstruction.pipeline import finish_frame
    from tests.reconstruction._scenes import unseen_frame

    procam, pattern, truth, o, frame = unseen_frame(185)
    assert frame.prep.traces is not None and frame.prep.traces.pos_of.dtype == np.int32
    narrow = finish_frame(frame)
    seen = {}
    orig_arrays, orig_pos = K.label_arrays, K.positions_of

    def label_arrays(q, family, unlabelled):
        fam, index, q_out, seed_jid, seed = orig_arrays(q, family, unlabelled)
        seen["narrow"] = (fam.dtype, index.dtype, seed_jid.dtype, seed.dtype)
        return fam.astype(np.intp), index.astype(np.float64), q_out, seed_jid.astype(np.int64), seed.astype(np.int64)

    monkeypatch.setattr(K, "label_arrays", label_arrays)
    monkeypatch.setattr(K, "positions_of", lambda P, sid: orig_pos(P, sid).astype(np.intp))
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
