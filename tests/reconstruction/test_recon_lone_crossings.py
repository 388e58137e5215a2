"""Pieces labelled at a crossing of unlabelled pieces (decision 0139, reconstruction.lone_crossings): on the paper
presets' objects, every piece it labels carries its true line (simulator truth), coverage rises, and the new points
are accurate; the epipolar order rejects a crossing whose families are swapped; with the option off the step does
nothing."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import reconstruction.labelling as labelling
from benchmarks._common import bench_scenes, coverage_lines, relative_errors, render_scene, sample_bilinear
from benchmarks.grazing_faces import true_lines
from reconstruction.pipeline import ReconstructOptions, reconstruct
from reconstruction.rigmodel import UNLABELLED


@pytest.fixture(scope="module")
def paper_scenes():
    out = []
    for sc in bench_scenes(["paper-intermediate", "paper-orthogonal"], [], noise_grey=2.0):
        img, truth = render_scene(sc.procam, sc.scene, sc.pattern, noise_grey=sc.noise_grey)
        out.append((sc, img, truth))
    return out


def _options(sc, on: bool) -> ReconstructOptions:
    o = ReconstructOptions(depth_min_mm=sc.depth_range_mm[0], depth_max_mm=sc.depth_range_mm[1])
    return replace(o, trace=replace(o.trace, lone_crossings=on))


def test_new_points_carry_their_true_line_and_coverage_rises(paper_scenes):
    for sc, img, truth in paper_scenes:
        off = reconstruct(img, sc.procam, sc.pattern, options=_options(sc, False))
        on = reconstruct(img, sc.procam, sc.pattern, options=_options(sc, True))
        assert on.stats["samples_lone_crossings"] > 50 and off.stats["samples_lone_crossings"] == 0, sc.name
        cov_off = coverage_lines(truth, sc.pattern, off.q_cam)
        cov_on = coverage_lines(truth, sc.pattern, on.q_cam)
        assert cov_on > cov_off + 0.01, (sc.name, cov_off, cov_on)
        # the points the step adds: none off its true line, none more than 0.5 % off
        d = np.min(np.linalg.norm(on.q_cam[:, None, :].astype(np.float64) - off.q_cam[None, :, :], axis=2), axis=1)
        new = (d > 0.01) & (on.family > 0)
        assert new.sum() > 50, sc.name
        q = on.q_cam[new].astype(np.float64)
        ok = np.all(np.isfinite(sample_bilinear(truth.p_proj, q)), axis=1)
        tl = true_lines(sample_bilinear(truth.q_proj, q[ok]), sc.pattern)
        fam = on.family[new][ok]
        k_true = np.where(fam == 1, tl[1][2], tl[2][2])
        k_got = np.where(fam == 1, on.label[new][ok][:, 0], on.label[new][ok][:, 1])
        assert np.all(k_got != UNLABELLED)
        assert np.array_equal(k_got, k_true), (sc.name, int((k_got != k_true).sum()))
        rel = relative_errors(on.points_proj[new], on.q_cam[new], truth) * 100
        assert rel.max() < 0.5, (sc.name, rel.max())


def test_swapped_families_fail_the_epipolar_order(paper_scenes, monkeypatch):
    calls = []
    real = labelling.label_lone_crossings

    def spy(*a, **k):
        calls.append(([np.copy(x) if isinstance(x, np.ndarray) else x for x in a], dict(k)))
        return real(*a, **k)

    monkeypatch.setattr(labelling, "label_lone_crossings", spy)
    sc, img, truth = paper_scenes[0]
    reconstruct(img, sc.procam, sc.pattern, options=_options(sc, True))
    (q, fam, sid, piece, ts, index), kw = calls[0]
    right = real(q, fam, sid, piece, ts, np.copy(index), **kw)
    assert right["nodes_labelled"] >= 2
    swapped = real(q, np.where(fam == 1, 2, 1), sid, piece, ts, np.copy(index), **kw)
    assert swapped["nodes"] >= 2  # the same crossings are found
    assert swapped["nodes_labelled"] == 0 and swapped["samples"] == 0


def test_off_labels_nothing_and_is_the_default_path(paper_scenes, monkeypatch):
    called = []
    monkeypatch.setattr(labelling, "label_lone_crossings", lambda *a, **k: called.append(1) or {"samples": 0})
    sc, img, truth = paper_scenes[0]
    res = reconstruct(img, sc.procam, sc.pattern, options=_options(sc, False))
    assert not called and res.stats["samples_lone_crossings"] == 0
    # the paper labeller's output stays the paper's method
    reconstruct(img, sc.procam, sc.pattern, options=replace(_options(sc, True), labeller="paper"))
    assert not called


def test_small_scene_without_any_junction_label_gets_true_indices(small_scene):
    """The small scene (tilted plane and sphere) with every junction label taken away: the other steps that label
    pieces without junctions off, the lone crossings alone label thousands of samples, each with its true line."""
    import cv2

    from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
    from reconstruction.labelling import TraceOptions, label_samples
    from reconstruction.rigmodel import rig_model

    s = small_scene
    model = rig_model(s.procam, s.pattern, s.depth_range_mm)
    obs = extract_grid(s.image, model, options=ExtractOptions())
    labels = np.full((len(obs.q_junction), 2), UNLABELLED, np.int64)
    sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))
    alone = dict(continue_lines=False, piece_seeds=False, piece_junctions=False, cross_rounds=0, cross_rounds_after=0,
                 beside_lines_ends=False, surface_labels=False, beside_lines=False, depth_range_labels=False)

    def run(on: bool):
        return label_samples(obs, labels, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]),
                             options=TraceOptions(**alone, lone_crossings=on), model=model, depth_range_mm=s.depth_range_mm,
                             image=s.image, line_width_px=model.line_width_cam_px)

    off, on = run(False), run(True)
    assert not np.isfinite(off.index).any()
    new = np.isfinite(on.index)
    assert on.stats["samples_lone_crossings"] > 1000, on.stats["samples_lone_crossings"]
    m = on.q[new].astype(np.float32).reshape(-1, 1, 2)
    qp = cv2.remap(s.truth.q_proj.astype(np.float32), m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderValue=np.nan).reshape(-1, 2)
    fam = obs.family[new]
    n = np.where(fam == 1, s.pattern.n1, s.pattern.n2)
    true = ((qp[:, 1] - s.pattern.centre_px[1]) - n * (qp[:, 0] - s.pattern.centre_px[0])) / s.pattern.pitch_px
    known = np.isfinite(true)
    assert known.mean() > 0.95
    assert np.max(np.abs(true[known] - on.index[new][known])) < 0.3
