"""Decision 0163: decision 0106's end pass after `label_beside_lines`' compiled rounds (`_k_all`) takes the pieces'
table (end_pos, labelled, val) and the pieces the step labelled from what `_k_all` returns (its logged trace
positions) instead of walking every trace position again (`_k_end_rows_after`). Checked on the small rig's
pitch-16 scene (test_recon_limb.py's captured call): `_k_all`'s table is `_k_pieces` of the labels after the rounds,
the rows are `_k_end_rows`' bit for bit, and label_beside_lines labels the same with and without it."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.limb_lines import _k_all, _k_end_rows, _k_end_rows_after, _k_pieces, label_beside_lines

from tests.reconstruction.test_recon_limb import _call, _captured_call, stage16  # noqa: F401  (the fixture)


def _rounds(args, kw, margin=2.0, tol_px=1.0):
    index, jid = args[6].copy(), args[7].copy()
    x0, y0, cell, gw, gh, start, items, pos_of = kw["grid"]
    piece = args[3]
    model = kw["model"]
    was = np.isnan(index)
    out = _k_all(*args[:6], index, jid, int(piece[-1]) + 1, kw["anchor"], kw["min_samples"], float(kw["reach_px"]), float(kw["lateral_px"]),
                 float(kw["mix_sigma"] * kw["sigma_px"]), float(kw["across_px"]), float(tol_px), float(margin), float(kw["depth_range_mm"][0]),
                 float(kw["depth_range_mm"][1]), float(kw["trim_px"]), 8, x0, y0, cell, gw, gh, start, items, pos_of, *model._sheet_check_args)
    return out, index, jid, was


@pytest.mark.parametrize("margin,tol_px", [(2.0, 1.0), (1.5, 2.0)])
def test_end_rows_from_the_rounds_are_the_walk(stage16, margin, tol_px):  # noqa: F811
    args, kw = _captured_call(stage16)
    (ok, n_pieces, n_samples, _amb, _left, end_pos, labelled, val, log_x), index, _jid, was = _rounds(args, kw, margin, tol_px)
    assert ok and n_samples >= 150
    q, fam, sid, piece, _ts, tangent = args[:6]
    n_p = int(piece[-1]) + 1
    e0, l0, v0 = _k_pieces(sid, piece, index, n_p)
    np.testing.assert_array_equal(end_pos, e0)
    np.testing.assert_array_equal(labelled, l0)
    np.testing.assert_array_equal(val, v0)  # (NaN where unlabelled, in both)
    # the logged positions hold every sample the rounds labelled
    changed = np.flatnonzero(was[sid] & np.isfinite(index[sid]))
    assert len(changed) == n_samples and np.isin(changed, log_x).all()
    x0, y0, cell, gw, gh, start, items, pos_of = kw["grid"]
    common = (q, fam, sid, piece, tangent, index, was, n_p, int(kw["anchor"]), float(kw["reach_px"]), float(kw["lateral_px"]),
              x0, y0, cell, gw, gh, start, items, pos_of)
    ref = _k_end_rows(*common)
    got = _k_end_rows_after(*common, end_pos, labelled, val, log_x)
    assert len(ref[0]) > 0  # ends were found, so the rows were compared
    for a, b in zip(ref, got):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)


def test_labels_the_same_with_and_without(stage16):  # noqa: F811
    args, kw = _captured_call(stage16)
    new, index1, jid1 = _call(label_beside_lines, args, kw)
    old, index2, jid2 = _call(label_beside_lines, args, kw, end_rows_from_rounds=False)
    assert new == old and new["samples_ends"] > 0
    np.testing.assert_array_equal(index1, index2)
    np.testing.assert_array_equal(jid1, jid2)
