"""Points from a labelled line's end up to the crossing that ends it (decision 0099,
reconstruction.crossing_fill_one_sided), against simulator truth."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from benchmarks._common import sample_bilinear
from reconstruction.crossing_fill import CrossingFillOptions, fill_crossings
from reconstruction.crossing_fill_one_sided import OneSidedFillOptions, fill_one_sided, with_one_sided
from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import UNLABELLED, rig_model


def _read(img: np.ndarray, q: np.ndarray) -> np.ndarray:
    m = q.astype(np.float32).reshape(-1, 1, 2)
    return cv2.remap(img.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan).reshape(len(q), -1)


def _line_offset_px(pattern, truth, q, fam, index):
    """Projector px between the projector point each camera pixel q sees (truth) and the centre of line
    (fam, index) (uniform spacing)."""
    qp = _read(truth.q_proj, q)
    n = np.where(fam == 1, pattern.n1, pattern.n2)
    s = (qp[:, 1] - pattern.centre_px[1]) - n * (qp[:, 0] - pattern.centre_px[0])
    return np.abs(s - index * pattern.pitch_px) / np.hypot(1.0, n)


@pytest.fixture(scope="module")
def stages(small_scene):
    """The label stage's outputs on the small rig's plane and sphere, 0086's points, and the keywords of
    `with_one_sided` / `fill_one_sided` for that frame."""
    sc = small_scene
    model = rig_model(sc.procam, sc.pattern, sc.depth_range_mm)
    obs = extract_grid(sc.image, model)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1]))
    sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))
    sl = label_samples(obs, lab.labels, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]), options=TraceOptions(),
                       model=model, depth_range_mm=sc.depth_range_mm, image=sc.image, line_width_px=model.line_width_cam_px)
    cell = float(max(1, int(obs.stats.get("scale", 1))))
    cp = fill_crossings(sl.q, obs.family, sl.index, sl.junction, q_samples=obs.q, family_samples=obs.family, q_junction=obs.q_junction,
                        junction_dir=obs.junction_dir, junction_labels=lab.labels, model=model, sigma_px=sigma, cell_px=cell,
                        depth_range_mm=sc.depth_range_mm, options=CrossingFillOptions())
    kw = dict(q_samples=obs.q, family_samples=obs.family, q_junction=obs.q_junction, junction_labels=lab.labels, model=model,
              sigma_px=sigma, cell_px=cell, depth_range_mm=sc.depth_range_mm)
    return sc, model, obs, lab.labels, sl, cp, kw


def test_points_from_labelled_ends_lie_on_their_true_line_and_surface(stages):
    """Every added point lies on the centre of the line whose index it carries (projector px, truth) and
    its 3-D point on the true surface: the sphere's silhouettes and shadows get none beyond them."""
    sc, model, obs, labels, sl, cp, kw = stages
    out = with_one_sided(cp, sl.q, obs.family, sl.index, sl.junction, **kw)
    st = out.stats["one_sided"]
    n0 = len(cp.index)
    q_new, f_new, k_new = out.q[n0:], out.family[n0:], out.index[n0:]
    # measured: 340 points from 118 ends (of 338 looked at)
    assert len(q_new) == st["samples_one_sided_filled"] >= 250, st
    assert st["ends_filled"] >= 80
    d = _line_offset_px(sc.pattern, sc.truth, q_new, f_new, k_new)
    assert np.isfinite(d).all()
    # measured: median 0.047, p90 0.127, max 0.44 projector px (anchors from the end sample on, without
    # the 1σ pull margin: p90 0.20, max 1.12); the line is 3 px wide
    assert np.percentile(d, 90) <= 0.2, np.percentile(d, [50, 90, 100])
    assert d.max() <= 0.25 * sc.pattern.line_width_px, d.max()
    # the points on their light sheets against the true surface (relative 3-D error, %)
    p = model.intersect_light_sheets(model.cam_normalised(q_new), f_new, k_new.astype(np.intp))
    p_true = sample_bilinear(sc.truth.p_proj, q_new, dtype=np.float64)
    rel = np.linalg.norm(p - p_true, axis=1) / np.linalg.norm(p_true, axis=1) * 100
    # measured: median 0.037, p99 0.31, max 0.52 %
    assert np.isfinite(rel).all()
    assert np.percentile(rel, 99) <= 0.5 and rel.max() <= 1.0, np.percentile(rel, [50, 99, 100])
    # each added point lies beyond its line's labelled samples: none within half a sampling step
    ok = np.isfinite(sl.index)
    for f in (1, 2):
        m = f_new == f
        ref = ok & (obs.family == f)
        dmin = np.min(np.hypot(*(q_new[m][:, None, :] - sl.q[ref][None, :, :]).transpose(2, 0, 1))
                      + 1e9 * (k_new[m][:, None] != sl.index[ref][None, :]), axis=1)
        assert dmin.min() >= 0.5, dmin.min()


def test_no_crossing_no_points(stages):
    """Without 0086's points every gap's side is an end. Take the crossings of one family's lines away (no
    labelled junction, only that family's samples kept, so its lines' ends find no other line): none of its
    ends gets a point, while the other family's ends (which still cross the kept lines) do."""
    sc, model, obs, labels, sl, cp, kw = stages
    for f in (1, 2):
        keep = obs.family == f
        kw2 = dict(kw, q_samples=obs.q[keep], family_samples=obs.family[keep], junction_labels=np.full_like(labels, UNLABELLED))
        out = fill_one_sided(sl.q, obs.family, sl.index, sl.junction, index_samples=sl.index[keep], **kw2)
        # measured: 0 of family f; 1196 / 1405 of the other family
        assert (out.family == f).sum() == 0, out.stats
        assert (out.family == 3 - f).sum() >= 800, out.stats
        assert out.stats["ends_rejected"]["no_run"] >= 1000


def test_the_crossing_is_checked_on_the_line_the_other_run_carries(stages):
    """With the labelled junctions taken away, the ends are filled from the other family's runs, checked on
    light sheet k. Shift every label of the other family's samples by one line: the sheet check now names a
    line the run does not carry, and (almost) every end is rejected (with other_label off they pass again)."""
    sc, model, obs, labels, sl, cp, kw = stages
    kw2 = dict(kw, junction_labels=np.full_like(labels, UNLABELLED))
    # (beyond off: the shifted labels of the line's own family would trip the line-continues test instead)
    right = fill_one_sided(sl.q, obs.family, sl.index, sl.junction, index_samples=sl.index,
                           options=OneSidedFillOptions(beyond=False), **kw2)
    wrong = fill_one_sided(sl.q, obs.family, sl.index, sl.junction, index_samples=sl.index + 1.0,
                           options=OneSidedFillOptions(beyond=False), **kw2)
    unchecked = fill_one_sided(sl.q, obs.family, sl.index, sl.junction, index_samples=sl.index + 1.0,
                               options=OneSidedFillOptions(other_label=False, beyond=False), **kw2)
    # measured: 1680 ends filled with the right labels (every gap's sides: no 0086 points here), 9 with the
    # shifted ones, 1680 unchecked
    assert right.stats["ends_filled"] >= 1000, right.stats
    assert wrong.stats["ends_filled"] <= 0.02 * right.stats["ends_filled"], wrong.stats
    assert wrong.stats["ends_rejected"]["sheet_check"] >= 0.9 * right.stats["ends_filled"]
    assert unchecked.stats["ends_filled"] == right.stats["ends_filled"]
    d = _line_offset_px(sc.pattern, sc.truth, right.q, right.family, right.index)
    # measured: median 0.051, p90 0.132 projector px
    assert np.percentile(d, 90) <= 0.2, np.percentile(d, [50, 90, 100])


def test_pipeline_adds_them_for_the_default_labeller_only(small_scene):
    """reconstruct: the points are counted in the stats, the coverage does not fall, the paper labeller's
    output is the same with the option on or off, and nothing is added with decision 0086's fill off."""
    from benchmarks.bench_reconstruction import coverage

    sc = small_scene
    base = ReconstructOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1])
    res = {on: reconstruct(sc.image, sc.procam, sc.pattern, options=dataclasses.replace(base, one_sided=OneSidedFillOptions(enabled=on)))
           for on in (False, True)}
    n_added = res[True].stats["samples_one_sided_filled"]
    assert res[False].stats["samples_one_sided_filled"] == 0
    assert n_added >= 100
    assert res[True].n_points >= res[False].n_points + 0.9 * n_added
    assert res[True].stats["samples_labelled"] == res[False].stats["samples_labelled"] + n_added
    assert coverage(sc.truth, sc.pattern, res[True].q_cam) >= coverage(sc.truth, sc.pattern, res[False].q_cam)
    paper = {on: reconstruct(sc.image, sc.procam, sc.pattern,
                             options=dataclasses.replace(base, labeller="paper", one_sided=OneSidedFillOptions(enabled=on)))
             for on in (False, True)}
    assert paper[True].stats["samples_one_sided_filled"] == 0
    assert np.array_equal(paper[True].points_proj, paper[False].points_proj)
    # it extends decision 0086's fill: with that off, nothing is added either
    no_0086 = reconstruct(sc.image, sc.procam, sc.pattern, options=dataclasses.replace(base, crossing=CrossingFillOptions(enabled=False)))
    assert no_0086.stats["samples_one_sided_filled"] == 0 and no_0086.stats["samples_crossing_filled"] == 0


def test_shared_work_gives_the_same_points_bit_for_bit(stages):
    """The two-sided fill's grids and order, reused (`CrossingPoints.shared`), give exactly the points of
    the one-sided fill computing them itself; arrays other than those the work came from are not reused."""
    sc, model, obs, labels, sl, cp, kw = stages
    assert cp.shared is not None and cp.shared.grids is not None and len(cp.index) > 0
    shared = with_one_sided(cp, sl.q, obs.family, sl.index, sl.junction, **kw)
    alone = with_one_sided(dataclasses.replace(cp, shared=None), sl.q, obs.family, sl.index, sl.junction, **kw)
    assert len(shared.q) > len(cp.q)
    for f in ("q", "family", "index", "junction"):
        assert np.array_equal(getattr(shared, f), getattr(alone, f)), f
    # a copy of the samples is not the array the work came from: the one-sided fill computes its own
    assert with_one_sided(cp, sl.q.copy(), obs.family, sl.index, sl.junction, **kw).stats == shared.stats


def test_order_with_appended_is_the_full_sort():
    """`order_with_appended` = the full sort (`_k_order`, `_sorted_by_key`) of old + appended samples: lines
    in random order, appended samples inside the old range (the merge), beyond it (the range grows: the
    full sort), and on an old sample's key (a tie: the full sort)."""
    from reconstruction import crossing_fill as CF

    rng = np.random.default_rng(7)
    d1 = np.array([1.0, 0.0])
    d2 = np.array([0.0, 1.0])
    for case in ("inside", "beyond", "tie"):
        n0, n1 = 3000, 400
        q = rng.uniform(0.0, 1000.0, (n0 + n1, 2))
        fam = rng.integers(1, 3, n0 + n1).astype(np.intp)
        idx = rng.integers(-20, 21, n0 + n1).astype(np.float64)
        idx[rng.random(n0 + n1) < 0.1] = np.nan  # unlabelled samples take no part
        q[n0:] = rng.uniform(10.0, 990.0, (n1, 2))  # inside the old samples' positions
        if case == "beyond":
            q[n0 + 5] = (1500.0, 1500.0)
        if case == "tie":
            q[n0 + 7], fam[n0 + 7], idx[n0 + 7] = q[11], fam[11], 3.0
            idx[11] = 3.0
        sel, key, key_range = CF._k_order_range(q[:n0], fam[:n0], idx[:n0], d1, d2)
        order0, key0 = CF._sorted_with_keys(sel, key)
        assert np.array_equal(order0, CF._sorted_by_key(sel, key))
        assert np.array_equal(key0, np.sort(key))
        shared = CF.FillShared((), n0, order0, key0, key_range, 1.0, None)
        app, app_key, inside = CF._k_appended_keys(key_range, n0, q, fam, idx, d1, d2)
        assert inside == (case != "beyond")
        if inside:
            merged_ok = CF._k_merge(order0, key0, *CF._sorted_with_keys(app, app_key))[1]
            assert merged_ok == (case == "inside")
        want = CF._sorted_by_key(*CF._k_order(q, fam, idx, d1, d2))
        got = CF.order_with_appended(shared, q, fam, idx, d1, d2)
        assert np.array_equal(got, want), case
        # the order itself: by family, then line index, then position along the line
        t = np.where(fam[got] == 1, q[got, 0], q[got, 1])
        lex = np.lexsort((t, idx[got], fam[got]))
        if case != "tie":
            assert np.array_equal(lex, np.arange(len(got)))
