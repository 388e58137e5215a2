"""Decision 0149: work the three point-adding steps of the label stage share (reconstruction.crossing_fill,
crossing_fill_one_sided, border_fill). Each shared structure must equal the one it stands for, recomputed:
the order of the samples with the two-sided fill's points put in at their gaps (`_k_insert_order`) = the full
sort; the lines' boxes (`_k_order_range_box`, `_k_mark_box`) = the walk over every sample (`_k_mark_lines`);
and the fills' points with the shared work = without it, bit for bit, on simulated frames."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks._common import bench_scenes, render_scene
from reconstruction import border_fill as BF
from reconstruction import crossing_fill as CF
from reconstruction import crossing_fill_one_sided as OS
from reconstruction.border_fill import with_border
from reconstruction.crossing_fill import CrossingFillOptions, fill_crossings
from reconstruction.crossing_fill_one_sided import OneSidedFillOptions, with_one_sided
from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.rigmodel import rig_model


def _stages(sc, image):
    """The label stage and the two-sided fill on `image`; the keywords of the later fills."""
    model = rig_model(sc.procam, sc.pattern, sc.depth_range_mm)
    obs = extract_grid(image, model)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1]))
    sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))
    sl = label_samples(obs, lab.labels, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]), options=TraceOptions(),
                       model=model, depth_range_mm=sc.depth_range_mm, image=image, line_width_px=model.line_width_cam_px)
    cell = float(max(1, int(obs.stats.get("scale", 1))))
    common = dict(q_samples=obs.q, family_samples=obs.family, model=model, sigma_px=sigma, cell_px=cell, depth_range_mm=sc.depth_range_mm)
    cp = fill_crossings(sl.q, obs.family, sl.index, sl.junction, q_junction=obs.q_junction, junction_dir=obs.junction_dir,
                        junction_labels=lab.labels, options=CrossingFillOptions(), **common)
    one = dict(common, q_junction=obs.q_junction, junction_labels=lab.labels, options=OneSidedFillOptions())
    return model, obs, sl, cp, one, dict(common, image=image)


@pytest.fixture(scope="module")
def frames(small_scene):
    """The small rig's plane and sphere (crossings filled, no line near the border) and the paper-parallel
    preset (lines up to the border: the border fill adds points)."""
    sc = bench_scenes(["paper-parallel"], [], noise_grey=2.0)[0]
    image, _truth = render_scene(sc.procam, sc.scene, sc.pattern, noise_grey=2.0)
    return {"small": _stages(small_scene, small_scene.image), "paper-parallel": _stages(sc, image)}


def _full_order(q, fam, idx, model):
    d1, d2 = CF._family_directions(model)
    return CF._sorted_by_key(*CF._k_order(q, fam, idx, d1, d2))


@pytest.mark.parametrize("name", ["small", "paper-parallel"])
def test_inserted_order_is_the_full_sort(frames, name):
    """`FillShared.order_all` (the two-sided fill's points put in at their gaps) is given on these frames and
    equals the full sort of the samples with those points appended, and `order_with_appended`'s merge."""
    model, obs, sl, cp, one, _bk = frames[name]
    sh = cp.shared
    assert len(cp.index) > 0 and sh.order_all is not None
    assert sh.points[0] is cp.q and sh.points[1] is cp.family and sh.points[2] is cp.index
    q = np.concatenate([sl.q, cp.q])
    fam = np.concatenate([obs.family.astype(np.intp), cp.family.astype(np.intp)])
    idx = np.concatenate([sl.index, cp.index])
    want = _full_order(q, fam, idx, model)
    assert np.array_equal(sh.order_all, want)
    # the lines' boxes `_k_gaps` kept along the order = those of every labelled sample
    kb = int(model.index_min)
    box = CF._k_order_range_box(sl.q, obs.family.astype(np.intp), sl.index, *CF._family_directions(model), kb, int(model.index_max) - kb + 1)[3]
    assert sh.box is not None and sh.box_kmin == kb and np.array_equal(sh.box, box)
    assert np.isfinite(box).all(axis=2).sum() >= 10
    d1, d2 = CF._family_directions(model)
    assert np.array_equal(CF.order_with_appended(dataclasses.replace(sh, order_all=None), q, fam, idx, d1, d2), want)


def test_insertion_refuses_what_is_not_the_order():
    """`_k_insert_order` on synthetic lines: points strictly inside their gap come out as the full sort; a point
    beyond the gap's far sample (keys not increasing), outside the key range, of another line, or not finite
    gives ok False (the caller then sorts)."""
    rng = np.random.default_rng(3)
    d1 = np.array([1.0, 0.0])
    d2 = np.array([0.0, 1.0])
    n0 = 2000
    fam = rng.integers(1, 3, n0).astype(np.intp)
    idx = rng.integers(-10, 11, n0).astype(np.float64)
    q = rng.uniform(0.0, 800.0, (n0, 2))
    sel, key, key_range = CF._k_order_range(q, fam, idx, d1, d2)
    order, key_s = CF._sorted_with_keys(sel, key)
    # gaps between consecutive samples of one line at least 3 px apart along the family's axis
    t = np.where(fam == 1, q[:, 0], q[:, 1])
    pos = [p for p in range(len(order) - 1) if fam[order[p]] == fam[order[p + 1]] and idx[order[p]] == idx[order[p + 1]]
           and t[order[p + 1]] - t[order[p]] > 3.0][:60]
    assert len(pos) >= 30
    cell = 1.0

    def make(pos, shift=0.0):
        gaps = np.zeros((len(pos), 8))
        rows = []
        for g, p in enumerate(pos):
            a, b = order[p], order[p + 1]
            L = np.hypot(*(q[b] - q[a]))
            gaps[g, 0], gaps[g, 3] = a, L
            n_pts = CF._n_gap_points(L, cell)
            for k in range(1, n_pts + 1):
                rows.append((q[a] + (k / (n_pts + 1) + shift) * (q[b] - q[a]), fam[a], idx[a]))
        qn = np.array([r[0] for r in rows]).reshape(-1, 2)
        fn = np.array([r[1] for r in rows], np.intp)
        kn = np.array([r[2] for r in rows])
        return gaps, qn, fn, kn

    gp = np.array(pos, np.intp)
    gaps, qn, fn, kn = make(pos)
    acc = np.ones(len(pos), np.bool_)
    acc[::7] = False  # gaps not filled take no points
    keep = np.repeat(acc, [CF._n_gap_points(L, cell) for L in gaps[:, 3]])
    qn, fn, kn = qn[keep], fn[keep], kn[keep]
    out, ok = CF._k_insert_order(order, key_s, key_range, gp, gaps, acc, cell, qn, fn, kn, n0, d1, d2)
    assert ok
    q_all, f_all, k_all = np.concatenate([q, qn]), np.concatenate([fam, fn]), np.concatenate([idx, kn])
    want = CF._sorted_by_key(*CF._k_order(q_all, f_all, k_all, d1, d2))
    assert np.array_equal(out, want)

    def refused(qn2, fn2, kn2):
        return not CF._k_insert_order(order, key_s, key_range, gp, gaps, acc, cell, qn2, fn2, kn2, n0, d1, d2)[1]

    beyond = qn.copy()
    beyond[5] = q[order[pos[1] + 1]] + (q[order[pos[1] + 1]] - q[order[pos[1]]])  # past the gap's far sample
    assert refused(beyond, fn, kn)
    other = kn.copy()
    other[3] = other[3] + 1.0  # another line's index
    assert refused(qn, fn, other)
    far = kn.copy()
    far[3] = 50.0  # outside the key range
    assert refused(qn, fn, far)
    nan = qn.copy()
    nan[4, 1] = np.nan
    assert refused(nan, fn, kn)
    assert refused(qn[:-1], fn[:-1], kn[:-1])  # fewer points than the gaps take


def test_line_boxes_mark_the_lines_the_walk_marks():
    """`_k_mark_box` on `_k_order_range_box`'s boxes = `_k_mark_lines` over the samples, for lines near and
    far from the border, samples on the limit, indices outside the model's range; a labelled sample without a
    finite position is counted (odd), where the border fill walks the samples instead."""
    rng = np.random.default_rng(11)
    d1 = np.array([0.8, 0.6])
    d2 = np.array([-0.6, 0.8])
    W, H = 640.0, 480.0
    for trial in range(40):
        n = int(rng.integers(200, 3000))
        fam = rng.integers(0, 4, n).astype(np.intp)
        idx = rng.integers(-25, 26, n).astype(np.float64)
        # each line's samples within 40 px of its own centre: some lines near the border, most not
        centre = np.column_stack([rng.uniform(0.0, W, (4, 51)).ravel(), rng.uniform(0.0, H, (4, 51)).ravel()])
        q = centre[fam * 51 + idx.astype(np.intp) + 25] + rng.uniform(-40.0, 40.0, (n, 2))
        idx[rng.random(n) < 0.1] = np.nan
        lim = float(rng.uniform(0.0, 30.0))
        q[: n // 100, 0] = lim  # on the limit
        kmin, nk = -20, 41
        if trial % 5 == 4:
            q[0] = (np.nan, 10.0)
            fam[0], idx[0] = 1, 3.0
        _sel, _key, _rng, box, odd = CF._k_order_range_box(q, fam, idx, d1, d2, kmin, nk)
        assert odd == (1 if trial % 5 == 4 else 0)
        walk = np.zeros((2, nk), np.bool_)
        BF._k_mark_lines(q, fam, idx, W - 1, H - 1, lim, kmin, walk)
        boxed = np.zeros((2, nk), np.bool_)
        BF._k_mark_box(box, W - 1, H - 1, lim, boxed)
        if odd == 0:
            assert np.array_equal(walk, boxed), trial
        assert walk.any() and not walk.all()


@pytest.mark.parametrize("name", ["small", "paper-parallel"])
def test_fills_with_shared_work_equal_the_fills_without(frames, name):
    """The one-sided fill with the inserted order and the border fill with the lines' boxes give the points of
    both computed without any shared work, bit for bit; the border fill adds points on paper-parallel."""
    model, obs, sl, cp, one, bk = frames[name]
    got = with_border(with_one_sided(cp, sl.q, obs.family, sl.index, sl.junction, **one), sl.q, obs.family, sl.index, sl.junction, **bk)
    assert got.stats["samples_one_sided_filled"] > 0
    if name == "paper-parallel":
        assert got.stats["samples_border_filled"] > 0
    bare = dataclasses.replace(cp, shared=None)
    alone = with_border(with_one_sided(bare, sl.q, obs.family, sl.index, sl.junction, **one), sl.q, obs.family, sl.index, sl.junction, **bk)
    assert alone.shared is None
    for f in ("q", "family", "index", "junction"):
        assert np.array_equal(getattr(got, f), getattr(alone, f)), f
    assert got.stats == alone.stats
    # a copy of the samples is not the array the boxes came from: the border fill walks them, same points
    cp1 = with_one_sided(cp, sl.q, obs.family, sl.index, sl.junction, **one)
    copy = with_border(cp1, sl.q.copy(), obs.family, sl.index, sl.junction, **bk)
    assert np.array_equal(copy.q, got.q) and copy.stats == got.stats


def _beyond_3x3(ox, oy, ux, uy, s_c, reach, width, f, k, qs, ks, x0, y0, gcell, gw, gh, start, mid, items, same):
    """`crossing_fill_one_sided._beyond` before decision 0149 (all of the 3×3 cells read), verbatim in Python."""
    mx = ox + (s_c + 0.5 * reach) * ux
    my = oy + (s_c + 0.5 * reach) * uy
    gx = int((mx - x0) / gcell)
    gy = int((my - y0) / gcell)
    out = 0
    for cy in range(max(gy - 1, 0), min(gy + 2, gh)):
        for cx in range(max(gx - 1, 0), min(gx + 2, gw)):
            c = cy * gw + cx
            t0 = start[c] if f == 1 else mid[c]
            t1 = mid[c] if f == 1 else start[c + 1]
            for t in range(t0, t1):
                i = items[t]
                if not np.isfinite(ks[i]):
                    continue
                ex = qs[i, 0] - ox
                ey = qs[i, 1] - oy
                s = ex * ux + ey * uy
                if s <= s_c or s > s_c + reach or abs(-ex * uy + ey * ux) > width:
                    continue
                if ks[i] != k:
                    return 1
                out = 2
    return out if same else 0


def test_beyond_reads_only_the_cells_of_its_box():
    """`_beyond` reading only the cells its region's bounding box reaches = the former 3×3 read, on random
    frames: dense samples on a few lines, regions at the grid's edges and outside it (clamped cells), every
    direction, samples on the region's limits."""
    rng = np.random.default_rng(5)
    n_diff = 0
    for trial in range(30):
        P = 4000
        qs = rng.uniform(0.0, 300.0, (P, 2))
        fs = rng.integers(1, 3, P).astype(np.intp)
        ks = np.where(rng.random(P) < 0.8, rng.integers(-3, 4, P).astype(np.float64), np.nan)
        gcell = float(rng.uniform(6.0, 20.0))
        x0, y0, gw, gh, start, mid, items = CF._family_grid(qs, fs, gcell)
        for _ in range(200):
            ox, oy = rng.uniform(-30.0, 330.0, 2)
            a = rng.uniform(0.0, 2.0 * np.pi)
            ux, uy = np.cos(a), np.sin(a)
            s_c, reach, width = float(rng.uniform(0.0, 5.0)), float(rng.uniform(1.0, 12.0)), float(rng.uniform(0.5, 6.0))
            f, k, same = int(rng.integers(1, 3)), float(rng.integers(-3, 4)), bool(rng.random() < 0.5)
            if rng.random() < 0.2:  # a sample on the region's far limit
                i = int(rng.integers(P))
                qs_i = (ox + (s_c + reach) * ux - width * uy, oy + (s_c + reach) * uy + width * ux)
                qs[i] = qs_i
                x0, y0, gw, gh, start, mid, items = CF._family_grid(qs, fs, gcell)
            args = (ox, oy, ux, uy, s_c, reach, width, f, k, qs, ks, x0, y0, gcell, gw, gh, start, mid, items, same)
            want = _beyond_3x3(*args)
            assert OS._beyond(*args) == want
            n_diff += want != 0
    assert n_diff > 500  # most regions hold samples


def test_appending_nothing_keeps_the_points():
    """`appended` with no new point returns the points and stats the concatenation gives (values, dtypes,
    shapes), without copying; with new points, the concatenation."""
    rng = np.random.default_rng(2)
    cp = CF.CrossingPoints(rng.uniform(0, 100, (50, 2)), rng.integers(1, 3, 50).astype(np.intp), rng.integers(-5, 5, 50).astype(float),
                           rng.integers(-1, 9, 50).astype(np.int64), {"samples_crossing_filled": 50})
    none = CF.CrossingPoints(np.zeros((0, 2)), np.zeros(0, np.intp), np.zeros(0), np.zeros(0, np.int64), {"n": 0})
    some = CF.CrossingPoints(rng.uniform(0, 100, (3, 2)), np.ones(3, np.intp), np.zeros(3), np.zeros(3, np.int64), {"n": 3})
    for new in (none, some):
        got = CF.appended(cp, new, "n", "extra")
        for f in ("q", "family", "index", "junction"):
            want = np.concatenate([getattr(cp, f), getattr(new, f).astype(getattr(cp, f).dtype)])
            assert np.array_equal(getattr(got, f), want) and getattr(got, f).dtype == want.dtype and getattr(got, f).shape == want.shape
        assert got.stats == {"samples_crossing_filled": 50, "n": new.stats["n"], "extra": new.stats}
    assert CF.appended(cp, none, "n", "extra").q is cp.q
    # float32 points would be widened by the concatenation: then it is done
    cp32 = dataclasses.replace(cp, q=cp.q.astype(np.float32))
    assert CF.appended(cp32, none, "n", "extra").q.dtype == np.float64
