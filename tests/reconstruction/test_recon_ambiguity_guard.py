"""Decision 0141: sample labels that an ambiguous junction component rules out are taken back.

- The kernels on a synthetic frame: a piece labelled with another index than an ambiguous junction's best label on
  its line loses its label (all of it), a piece with the same index keeps it, samples off the junction's line or
  beyond the seed radius are not read, a labelled sample on no piece loses its own label only.
- Unseen seed 198 (the scene where it was found, `benchmarks.unseen.draw_scene`): a graph of piece junctions joined
  across a depth edge by a lattice vector along the epipolar lines took a whole surface 3 lines off (2.6 % of the
  points more than 1 % off); the found junctions there were left out as ambiguous, their best offset the true one.
  With the guard the share is within the 0.5 % target; without it, it is not (the test can fail).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from reconstruction.ambiguity_guard import Guard, attached_pairs, unlabel_conflicts
from reconstruction.rigmodel import UNLABELLED


def _frame():
    """Two family-1 pieces along y = 0 and y = 10 (x 0..20), one family-2 piece along x = 30, a loose family-1
    sample at (8, 0.2) on no piece; ambiguous junctions at (10, 0) and (10, 10) with best labels (3, 7) and (4, 7),
    a labelled-elsewhere junction (UNLABELLED best) at (30, 5)."""
    xs = np.arange(0, 21, dtype=np.float64)
    q = np.concatenate([np.column_stack([xs, np.zeros(21)]), np.column_stack([xs, np.full(21, 10.0)]),
                        np.column_stack([np.full(11, 30.0), np.arange(0, 11, dtype=np.float64)]), [[8.0, 0.2]]])
    fam = np.concatenate([np.ones(42), np.full(11, 2), [1]]).astype(np.intp)
    piece = np.concatenate([np.zeros(21), np.ones(21), np.full(11, 2)]).astype(np.intp)
    sid = np.arange(53, dtype=np.intp)
    qj = np.array([[10.0, 0.0], [10.0, 10.0], [30.0, 5.0]])
    jdir = np.zeros((3, 2, 2))
    jdir[:, 0] = (1.0, 0.0)  # family-1 lines run along x
    jdir[:, 1] = (0.0, 1.0)
    amb = np.array([[3, 7], [4, 7], [UNLABELLED, UNLABELLED]], np.int64)
    return q, fam, piece, sid, qj, jdir, amb


def test_a_piece_labelled_against_the_best_offset_loses_its_label():
    q, fam, piece, sid, qj, jdir, amb = _frame()
    valid = np.ones(len(q), np.bool_)
    index = np.full(len(q), np.nan)
    index[:21] = 5.0  # piece 0: another line than the junction's best (3)
    index[21:42] = 4.0  # piece 1: the best label's line
    index[42:53] = 9.0  # piece 2: family 2, near no ambiguous junction
    index[53] = 5.0  # the loose sample
    seed_jid = np.zeros(len(q), np.int64)
    g = Guard(q, fam, valid, qj, jdir, amb, radius_px=4.0, lateral_px=1.0)
    pairs = set(g.pair_s.tolist())
    assert pairs == set(range(6, 15)) | set(range(27, 36)) | {53}  # within 4 px of (10, 0) / (10, 10), on the line
    n = g(index, seed_jid, piece, sid)
    assert np.isnan(index[:21]).all() and (seed_jid[:21] == -1).all()  # the whole piece, not only the pairs
    assert (index[21:42] == 4.0).all() and (index[42:53] == 9.0).all()
    assert np.isnan(index[53]) and n == 22
    assert g(index, seed_jid, piece, sid) == 0  # nothing left to take back


def test_samples_off_the_junction_line_are_not_read():
    q, fam, piece, sid, qj, jdir, amb = _frame()
    q = q.copy()
    q[:21, 1] = 1.5  # piece 0 runs 1.5 px beside the junction's family-1 line: another line, not this junction's
    s, e = attached_pairs(q, fam, np.ones(len(q), np.bool_), qj, np.array([0, 1], np.intp), amb[:2].copy(), jdir, 4.0, 1.0)
    assert not (s < 21).any()
    index = np.full(len(q), 5.0)
    seed_jid = np.zeros(len(q), np.int64)
    from reconstruction._label_kernels import positions_of

    unlabel_conflicts(s, e, index, seed_jid, positions_of(len(q), sid), piece, sid, np.zeros(len(q), np.bool_))
    assert (index[:21] == 5.0).all()  # not read: kept
    assert np.isnan(index[21:42]).all()  # on junction 1's line with 5 instead of 4


def test_seed_198_ghost_surface_taken_back():
    """Against simulated truth: with the guard the share of points more than 1 % off is within the target and no
    more than a handful of samples carry a wrong index; without it the ghost surface is back."""
    from benchmarks._common import relative_errors, sample_bilinear
    from reconstruction.pipeline import finish_frame
    from tests.reconstruction._scenes import unseen_frame

    procam, pattern, truth, o, frame = unseen_frame(198)
    dr = (o.depth_min_mm, o.depth_max_mm)
    out = {}
    for on in (True, False):
        res = finish_frame(replace(frame, options=replace(o, trace=replace(o.trace, ambiguity_guard=on))))
        rel = relative_errors(res.points_proj, res.q_cam, truth)
        out[on] = (float((rel > 0.01).mean()), res.n_points)
    assert out[True][0] <= 0.005 < out[False][0]
    assert out[True][1] >= 0.95 * out[False][1]
    # the ambiguous components' best labels, the guard's reference, are the true ones here
    from reconstruction.labelling import label_epipolar

    lab = label_epipolar(frame.obs, frame.model, frame.model.cam_normalised(frame.obs.q_junction),
                         options=replace(o.label, depth_min_mm=dr[0], depth_max_mm=dr[1]))
    amb = lab.ambiguous_best
    k = amb[:, 0] != UNLABELLED
    assert k.sum() >= 10
    assert (lab.labels[k, 0] == UNLABELLED).all()  # only junctions left out carry a best label
    qp = sample_bilinear(truth.q_proj, frame.obs.q_junction[k])
    d = np.linalg.norm(qp - pattern.junction_uv(amb[k, 0], amb[k, 1]), axis=1)
    assert np.mean(d <= 2) >= 0.9


def test_labels_spread_from_labelled_junctions_are_protected():
    """Samples already labelled when the guard is made (the labelled junctions' seeds, spread along their pieces) are
    neither read nor unlabelled; a later label on the same piece that conflicts is taken back around them."""
    q, fam, piece, sid, qj, jdir, amb = _frame()
    valid = np.ones(len(q), np.bool_)
    index = np.full(len(q), np.nan)
    index[:10] = 5.0  # piece 0's first half: spread from a labelled junction (conflicts with the best label 3)
    g = Guard(q, fam, valid, qj, jdir, amb, radius_px=4.0, lateral_px=1.0, index=index)
    seed_jid = np.zeros(len(q), np.int64)
    assert g(index, seed_jid, piece, sid) == 0 and (index[:10] == 5.0).all()
    index[10:21] = 5.0  # a later step labels the rest of the piece: pairs 10..14 conflict
    assert g(index, seed_jid, piece, sid) == 11
    assert (index[:10] == 5.0).all() and np.isnan(index[10:21]).all()
