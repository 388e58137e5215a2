"""Pieces labelled from a crossing with a labelled line at one end, confirmed by the crossing at the other end
on their own light sheet (decision 0089, reconstruction.piece_seeds), against simulator truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.piece_seeds import _SIN_MIN_CROSSING
from reconstruction.rigmodel import UNLABELLED, rig_model
from tests.reconstruction._truth import object_at, true_index
from tests.reconstruction._scenes import PINHOLE_PATTERN, pinhole_procam, planes_meet
from tests.reconstruction._scenes import collinear_plate as collinear_plate_scene


def _run(procam, pattern, image, depth_range, keep_junction):
    """label_samples with and without piece_seeds, the junction labels kept only where keep_junction(q_junction)."""
    model = rig_model(procam, pattern, depth_range)
    obs = extract_grid(image, model)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=depth_range[0], depth_max_mm=depth_range[1])).labels.copy()
    lab[~keep_junction(obs.q_junction)] = UNLABELLED
    sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))

    def run(on: bool):
        return label_samples(obs, lab, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]),
                             options=dataclasses.replace(TraceOptions(), piece_seeds=on, piece_junctions=False, beside_lines_ends=False,
                                                         lone_crossings=False), model=model, depth_range_mm=depth_range,
                             image=image, line_width_px=model.line_width_cam_px)

    return obs, run(False), run(True)


def test_pieces_seeded_at_one_end_lie_on_their_true_line(small_scene):
    """Junction labels kept on the left of a slanted border only: the pieces at the labelled patch's border have
    one crossing with a labelled line; those piece_seeds labels carry their true line's index."""
    s = small_scene

    def left(qj):
        return qj[:, 0] + 0.4 * qj[:, 1] < 380.0

    obs, off, on = _run(s.procam, s.pattern, s.image, s.depth_range_mm, left)
    new = np.isfinite(on.index) & ~np.isfinite(off.index)
    assert new.sum() >= 300, new.sum()  # (1047 measured)
    # the other steps are unchanged where piece_seeds labelled nothing new
    both = np.isfinite(off.index)
    assert np.all(np.isfinite(on.index[both]))
    t = true_index(s.truth, s.pattern, obs.q[new], np.asarray(obs.family)[new])
    ok = np.isfinite(t)
    assert ok.mean() > 0.95
    assert np.all(np.abs(t[ok] - on.index[new][ok]) < 0.3), np.abs(t[ok] - on.index[new][ok]).max()


# --- a depth edge: decision 0084's collinear plate (a plate's line j = 6 continues a plane's line j = 0 in the
# image, both equally bright), distortion-free pinholes so that the construction is exact

_DEPTH = (500.0, 1200.0)


@pytest.fixture(scope="module")
def collinear_plate():
    procam, image, truth, _edge = collinear_plate_scene()
    return procam, PINHOLE_PATTERN, image, truth


def test_pieces_beyond_a_depth_edge_stay_unlabelled(collinear_plate):
    """Only the plate's junctions labelled: the plate's lines end at its silhouette, where the plane's lines
    (one of them collinear with a plate line) run on. A plane piece next to the plate has crossings with the
    plate's labelled lines at one end at most; no plane sample may be labelled by piece_seeds, and every newly
    labelled sample carries its true index. (In this rendered scene the plane's pieces stay unlabelled even
    with one-sided evidence, confirm_far=False: their ends lie beyond the crossing search's reach of the
    plate's lines; the synthetic test below builds the case where they do not.)"""
    procam, pattern, image, truth = collinear_plate

    def on_plate(qj):
        return object_at(truth, qj) > 0

    obs, off, on = _run(procam, pattern, image, _DEPTH, on_plate)
    new = np.isfinite(on.index) & ~np.isfinite(off.index)
    plane = object_at(truth, obs.q) == 0
    assert not np.any(new & plane), int(np.sum(new & plane))
    t = true_index(truth, pattern, obs.q[new], np.asarray(obs.family)[new])
    ok = np.isfinite(t)
    assert np.all(np.abs(t[ok] - on.index[new][ok]) < 0.3)


# --- the same trap with exact synthetic samples: a plane's piece whose near end meets a plate's labelled line
# exactly at a plate junction (its line is collinear with the plate's line j = 6 in the image)


def _image_line(procam, n_sheet, n_plane, d_plane, X_near, *, step_px=1.0):
    """The 3D line where a light sheet meets a plane, and a function giving its image point nearest X_near
    moved by s camera px along the image line."""
    X0, u = planes_meet(n_sheet, 0.0, n_plane, d_plane)
    X0 = X0 + ((X_near - X0) @ u) * u

    def proj(X):
        x = procam.R_proj_cam.T @ (X - procam.t_proj_cam)
        return procam.camera.K[:2, :2] @ (x[:2] / x[2]) + procam.camera.K[:2, 2]

    a, b = proj(X0), proj(X0 + u)
    d = (b - a) / np.linalg.norm(b - a)
    return a, d


def _synthetic_trap(pattern, procam):
    """Samples (q, fam), traces (sid, piece, ts, tangent), index and seed_jid: the plate's labelled line i (two
    pieces on either side of its junction with the plate's line 6, the mixing zone left out), the plane's
    unlabelled piece P of line j = 0 (collinear with the plate's line 6) starting past that junction, and the
    plane's unlabelled line i' crossing P's far end (two pieces). Returns those and P's piece id."""
    n1, n2, pitch = pattern.n1, pattern.n2, pattern.pitch_px
    sheet1 = lambda k: np.array([n1, -1.0, k * pitch / 1000.0])  # noqa: E731
    sheet2 = lambda k: np.array([n2, -1.0, k * pitch / 1000.0])  # noqa: E731
    C = procam.t_proj_cam
    n_bg = np.array([0.1, -0.2, -1.0])
    n_bg /= np.linalg.norm(n_bg)
    d_bg = n_bg @ np.array([0, 0, 950.0])
    X2, u2 = planes_meet(sheet2(0), 0.0, n_bg, d_bg)
    n_cam = np.cross(X2 - C, u2)
    n_cam /= np.linalg.norm(n_cam)
    X1, u1 = planes_meet(sheet2(6), 0.0, n_cam, n_cam @ C)
    Xc = X1 + ((np.array([0, 0, 700.0]) - X1) @ u1) * u1
    v = C - Xc
    n_pl = v - (v @ u1) * u1
    n_pl /= np.linalg.norm(n_pl)
    d_pl = n_pl @ Xc
    # the plate's junction (i, 6) nearest the plate's centre
    fi = (Xc[1] / Xc[2] * 1000.0 - n1 * Xc[0] / Xc[2] * 1000.0) / pitch
    i = int(round(fi))
    J1 = np.linalg.solve(np.array([sheet1(i), sheet2(6), n_pl]), [0.0, 0.0, d_pl])
    c1, d_i = _image_line(procam, sheet1(i), n_pl, d_pl, J1)
    _, d_6 = _image_line(procam, sheet2(6), n_pl, d_pl, J1)
    # the plane's line 0 through the same image point: the camera ray of c1 on the background plane
    ray = procam.R_proj_cam @ np.linalg.solve(procam.camera.K, [c1[0], c1[1], 1.0])
    Xb = C + ray * ((d_bg - n_bg @ C) / (n_bg @ ray))
    # the plane's next junction (i', 0) along +d_6 from c1, at least 14 px on
    cb, db = _image_line(procam, sheet2(0), n_bg, d_bg, Xb)
    db = db if db @ d_6 > 0 else -db
    cand = [np.linalg.solve(np.array([sheet1(k), sheet2(0), n_bg]), [0.0, 0.0, d_bg]) for k in range(-12, 13)]
    proj = lambda X: _image_line(procam, sheet2(0), n_bg, d_bg, X)[0]  # noqa: E731
    ahead = [(float((proj(X) - c1) @ db), k) for k, X in zip(range(-12, 13), cand)]
    t2, i2 = min((t, k) for t, k in ahead if t > 14.0)
    c2 = c1 + t2 * db
    J2 = cand[i2 + 12]
    _, d_i2 = _image_line(procam, sheet1(i2), n_bg, d_bg, J2)
    gap = 6.0
    pieces = [  # (points, family, index)
        ([c1 - s * d_i for s in np.arange(gap, gap + 12.0)], 1, float(i)),
        ([c1 + s * d_i for s in np.arange(gap, gap + 12.0)], 1, float(i)),
        ([c1 + s * db for s in np.arange(gap, t2 - gap + 0.5)], 2, np.nan),
        ([c2 - s * d_i2 for s in np.arange(gap, gap + 12.0)], 1, np.nan),
        ([c2 + s * d_i2 for s in np.arange(gap, gap + 12.0)], 1, np.nan),
    ]
    q = np.concatenate([np.array(p) for p, _, _ in pieces])
    fam = np.concatenate([np.full(len(p), f, np.intp) for p, f, _ in pieces])
    index = np.concatenate([np.full(len(p), k) for p, _, k in pieces])
    piece = np.concatenate([np.full(len(p), n, np.int64) for n, (p, _, _) in enumerate(pieces)])
    ts = np.concatenate([np.arange(len(p), dtype=float) for p, _, _ in pieces])
    tangent = np.concatenate([np.tile((np.array(p[-1]) - p[0]) / np.linalg.norm(np.array(p[-1]) - p[0]), (len(p), 1)) for p, _, _ in pieces])
    seed_jid = np.where(np.isfinite(index), 0, -1).astype(np.int64)
    return q, fam, np.arange(len(q), dtype=np.intp), piece, ts, tangent, index, seed_jid, 2, (i, i2)


@pytest.mark.parametrize("confirm_far", [True, False])
def test_a_piece_beyond_a_silhouette_is_not_labelled_from_one_crossing(confirm_far):
    """The near end's crossing is a true junction of the plate (i, 6) and passes the check on line i's sheet, so
    one-sided evidence labels the plane's piece 6 (its true line is 0: decision 0049's error). Its far crossing,
    the plane's junction (i', 0), lands on sheet 6 off the plate's next line i ± 1: rejected."""
    from reconstruction.labelling import _sample_grid
    from reconstruction.patterns import GridPattern
    from reconstruction.piece_seeds import seed_one_sided

    pattern = GridPattern(pitch_px=24.0, lines=25, centre_px=(399.5, 299.5), line_width_px=3.0)
    procam = pinhole_procam()
    model = rig_model(procam, pattern, _DEPTH)
    q, fam, sid, piece, ts, tangent, index, seed_jid, p_trap, _ = _synthetic_trap(pattern, procam)
    radius = 0.6 * model.junction_step_cam_px
    grid = _sample_grid(q, np.ones(len(q), bool), sid, max(radius, 14.0))
    stats = seed_one_sided(q, fam, sid, piece, ts, tangent, index, seed_jid, model=model, depth_range_mm=_DEPTH,
                           radius_px=max(radius, 14.0), grid=grid, confirm_far=confirm_far)
    trap = piece == p_trap
    if confirm_far:
        assert np.all(np.isnan(index[trap]))
        assert stats["far_rejected"] == 1
    else:  # the scenario is the trap: the near end alone names the plate's line 6
        assert np.all(index[trap] == 6.0)


def _end_line(p_end: int, first: np.ndarray, last: np.ndarray, piece: np.ndarray, ts: np.ndarray, q: np.ndarray, sid: np.ndarray,
              trim_px: float, anchor: int):
    """The line of a piece's end beyond the crossing's pull: the first sample at least trim_px (along the trace)
    inside from the end at trace position p_end, and the unit chord to it from the sample `anchor` places
    further in, as (x, y, ux, uy). None when the piece is too short."""
    p = piece[p_end]
    step = 1 if p_end == first[p] else -1
    stop = int(last[p] if step == 1 else first[p])
    t0 = float(ts[p_end])
    j = int(p_end)
    while j != stop and abs(float(ts[j]) - t0) < trim_px:
        j += step
    if abs(float(ts[j]) - t0) < trim_px:
        return None
    j2 = j
    for _ in range(anchor):
        if j2 == stop:
            break
        j2 += step
    ax, ay = float(q[sid[j], 0]), float(q[sid[j], 1])
    dx, dy = ax - float(q[sid[j2], 0]), ay - float(q[sid[j2], 1])
    L = math.hypot(dx, dy)
    if L < 1.5:
        return None
    return ax, ay, dx / L, dy / L


def _refined_crossing(p_far: int, o_partner: int, c0: np.ndarray, first, last, piece, ts, q, sid, trim_px: float, anchor: int):
    """The per-end Python code `_k_refine` replaced (decision 0089): the far crossing from both pieces' end lines beyond the crossing's pull (`_end_line`): the far end of this
    piece and the end of the partner's piece nearer c0. c0 when either piece is too short or the lines are
    nearly parallel."""
    own = _end_line(p_far, first, last, piece, ts, q, sid, trim_px, anchor)
    if own is None:
        return c0
    pp = piece[o_partner]
    f, g = int(first[pp]), int(last[pp])
    cx, cy = float(c0[0]), float(c0[1])
    df = math.hypot(float(q[sid[f], 0]) - cx, float(q[sid[f], 1]) - cy)
    dg = math.hypot(float(q[sid[g], 0]) - cx, float(q[sid[g], 1]) - cy)
    other = _end_line(f if df <= dg else g, first, last, piece, ts, q, sid, trim_px, anchor)
    if other is None:
        return c0
    ax, ay, ux, uy = own
    bx, by, vx, vy = other
    den = ux * vy - uy * vx
    if abs(den) < _SIN_MIN_CROSSING:
        return c0
    t = ((bx - ax) * vy - (by - ay) * vx) / den
    return np.array([ax + t * ux, ay + t * uy])


def test_compiled_refinement_equals_the_python_one():
    """`_k_refine` (all far ends in one compiled loop) against `_refined_crossing` (one end at a time), on random
    straight pieces with trims and anchors that leave some pieces too short (those keep their crossing)."""
    from reconstruction.piece_seeds import _k_refine

    rng = np.random.default_rng(11)
    n_p = 60
    lens = rng.integers(2, 14, n_p)
    piece = np.repeat(np.arange(n_p), lens)
    n = len(piece)
    first = np.concatenate(([0], np.cumsum(lens)[:-1])).astype(np.intp)
    last = (first + lens - 1).astype(np.intp)
    step = rng.uniform(0.7, 1.3, n)
    ts = np.zeros(n)
    q = np.zeros((n, 2))
    for p in range(n_p):
        a = rng.uniform(0, np.pi)
        d = np.array([np.cos(a), np.sin(a)])
        s = np.cumsum(step[first[p]:last[p] + 1]) - step[first[p]]
        ts[first[p]:last[p] + 1] = s
        q[first[p]:last[p] + 1] = rng.uniform(0, 200, 2) + s[:, None] * d + rng.normal(0, 0.2, (lens[p], 2))
    sid = rng.permutation(n).astype(np.intp)  # trace position -> sample id
    q_by_id = np.empty_like(q)
    q_by_id[sid] = q
    m = 200
    p_far = np.where(rng.random(m) < 0.5, first[rng.integers(0, n_p, m)], last[rng.integers(0, n_p, m)]).astype(np.int64)
    o_partner = rng.integers(0, n, m).astype(np.int64)
    c = rng.uniform(0, 200, (m, 2))
    for trim, anchor in ((0.0, 3), (2.5, 3), (3.0, 2)):
        want = c.copy()
        for r in range(m):
            want[r] = _refined_crossing(int(p_far[r]), int(o_partner[r]), c[r], first, last, piece, ts, q_by_id, sid, trim, anchor)
        got = c.copy()
        _k_refine(p_far, o_partner, np.arange(m, dtype=np.int64), got, first, last, piece, ts, q_by_id, sid, trim, anchor)
        # the same formulas; Python's math.hypot is correctly rounded, the C library's (numba) not always: last bits
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-12)
        assert (got != c).any(axis=1).sum() > 20, "most ends are refined"
