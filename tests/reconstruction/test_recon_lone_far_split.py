"""A lone crossing's piece whose far end fails decision 0139's crossing check (decision 0164, step 6b of
reconstruction.lone_crossings): cut at a ridge-brightness step the piece shows, kept whole where its line ends at
the far crossing (a T), left out where its own line goes on there. Analytic cases of `_far_split`, and on
paper-intermediate (whose pyramid line ends at the silhouette of the object in front) against simulator truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import reconstruction.labelling as labelling
from benchmarks._common import bench_scenes, coverage_lines, relative_errors, render_scene, sample_bilinear
from benchmarks.grazing_faces import true_lines
from reconstruction.lone_crossings import _far_split
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import UNLABELLED


def _ridge(values):
    r = np.asarray(values, np.float32)
    return r, np.arange(len(r), dtype=np.intp)


def test_visible_step_cuts_at_the_edge_on_either_side():
    # node side 62, the other surface 100 from position 20 on (the collinear line of unseen 125's piece)
    r, sid = _ridge([62.0 + (k % 3) for k in range(20)] + [100.0 + (k % 2) for k in range(15)])
    assert _far_split(r, sid, 0, 35, 1, 0.15, False, 4) == (1, 20)  # far end at the stop: keep 0 … 19
    assert _far_split(r, sid, 0, 35, 1, 0.15, True, 4) == (1, 20)  # the step decides, whatever the far crossing
    # far end at the start (the node at the stop): the node's side is the bright one, kept from the step on
    r2, sid2 = _ridge(r[::-1])
    assert _far_split(r2, sid2, 0, 35, 0, 0.15, False, 4) == (0, 15)
    # the kept part too short
    assert _far_split(r, sid, 0, 35, 1, 0.15, False, 25) is None
    # offsets a … b inside longer traces
    r3, sid3 = _ridge(np.r_[np.full(7, 5.0), r])
    assert _far_split(r3, sid3, 7, 42, 1, 0.15, False, 4) == (1, 27)


def test_no_visible_step_keeps_a_t_and_drops_an_x():
    # a gentle trend (77 → 72 grey, paper-intermediate's pyramid line): no edge on the piece
    r, sid = _ridge(np.linspace(77.0, 72.0, 54))
    assert _far_split(r, sid, 0, 54, 1, 0.15, False, 4) == (1, 54)  # a T: the whole piece
    assert _far_split(r, sid, 0, 54, 0, 0.15, False, 4) == (0, 0)
    assert _far_split(r, sid, 0, 54, 1, 0.15, True, 4) is None  # its line goes on: an X names another line
    # a step below the share is no edge
    r2, sid2 = _ridge([80.0] * 10 + [70.0] * 10)
    assert _far_split(r2, sid2, 0, 20, 1, 0.15, False, 4) == (1, 20)
    assert _far_split(r2, sid2, 0, 20, 1, 0.10, False, 4) == (1, 10)


@pytest.fixture(scope="module")
def intermediate():
    (sc,) = bench_scenes(["paper-intermediate"], [], noise_grey=2.0)
    img, truth = render_scene(sc.procam, sc.scene, sc.pattern, noise_grey=sc.noise_grey)
    return sc, img, truth


def _run(sc, img, on: bool, monkeypatch):
    stats = []
    real = labelling.label_lone_crossings
    monkeypatch.setattr(labelling, "label_lone_crossings", lambda *a, **k: stats.append(real(*a, **k)) or stats[-1])
    o = ReconstructOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1])
    res = reconstruct(img, sc.procam, sc.pattern, options=replace(o, trace=replace(o.trace, lone_far_split=on)))
    monkeypatch.setattr(labelling, "label_lone_crossings", real)
    return res, stats[0]


def test_the_line_at_a_silhouette_is_labelled_right(intermediate, monkeypatch):
    sc, img, truth = intermediate
    off, st_off = _run(sc, img, False, monkeypatch)
    on, st_on = _run(sc, img, True, monkeypatch)
    assert st_off.get("pieces_far_end", 0) >= 1 and "pieces_far_split" not in st_off
    assert st_on.get("pieces_far_split", 0) >= 1
    assert st_on["samples"] >= st_off["samples"] + 20
    assert coverage_lines(truth, sc.pattern, on.q_cam) > coverage_lines(truth, sc.pattern, off.q_cam) + 0.005
    # the points it adds: each on its true line, none more than 0.5 % off
    d = np.min(np.linalg.norm(on.q_cam[:, None, :].astype(np.float64) - off.q_cam[None, :, :], axis=2), axis=1)
    new = (d > 0.01) & (on.family > 0)
    assert new.sum() >= 20
    q = on.q_cam[new].astype(np.float64)
    ok = np.all(np.isfinite(sample_bilinear(truth.p_proj, q)), axis=1)
    tl = true_lines(sample_bilinear(truth.q_proj, q[ok]), sc.pattern)
    fam = on.family[new][ok]
    k_true = np.where(fam == 1, tl[1][2], tl[2][2])
    k_got = np.where(fam == 1, on.label[new][ok][:, 0], on.label[new][ok][:, 1])
    assert np.all(k_got != UNLABELLED)
    assert np.array_equal(k_got, k_true), int((k_got != k_true).sum())
    rel = relative_errors(on.points_proj[new], on.q_cam[new], truth) * 100
    assert rel.max() < 0.5, rel.max()
