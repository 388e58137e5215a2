"""Decision 0115: the samples' label-free bucket grids are built in the extraction stage, and `fill_gaps` takes the
labelled trace positions `label_samples` already found. The outputs must be those of the paths that build and
find them in the label stage, bit for bit; the prebuilt grids must equal a fresh build and stay unchanged."""

from __future__ import annotations

import dataclasses

import numpy as np

import reconstruction.labelling as labelling
from reconstruction import _label_kernels as _k
from reconstruction.crossing_fill import _family_grid, fill_grid_cell_px
from reconstruction.labelling import trace_grid_cell_px
from reconstruction.pipeline import ReconstructOptions, extract_frame, finish_frame


def _options(s) -> ReconstructOptions:
    return ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])


def _same(a, b) -> None:
    for name in ("points_proj", "q_cam", "label", "family", "junction_labels", "junctions_cam"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_prebuilt_grids_equal_a_fresh_build_and_give_the_same_points(small_scene_pitch16):
    s = small_scene_pitch16
    opts = _options(s)
    frame = extract_frame(s.image, s.procam, s.pattern, options=opts)
    obs, model, prep = frame.obs, frame.model, frame.prep
    cell = trace_grid_cell_px(model, opts.trace)
    gcell = fill_grid_cell_px(float(obs.stats["sigma_px"]), float(max(1, int(obs.stats.get("scale", 1)))), opts.crossing)
    assert set(prep.grids) == {("valid", cell), ("family", gcell)}
    q = np.ascontiguousarray(obs.q, np.float64)
    fam = np.asarray(obs.family).astype(np.intp)
    # the grid of the traces' searches: sample_grid_split's first six entries (its pos_of is the label stage's)
    ref = _k.sample_grid_split(q, prep.valid, fam, np.arange(5, dtype=np.intp), float(cell))
    got = prep.grids[("valid", cell)]
    assert len(got) == 6 and got[2] * got[3] > 1 and len(got[5]) == prep.n_valid
    for a, b in zip(got, ref[:6]):
        np.testing.assert_array_equal(a, b)
    ref_f = _family_grid(q, fam, float(gcell))
    for a, b in zip(prep.grids[("family", gcell)], ref_f):
        np.testing.assert_array_equal(a, b)
    kept = [np.array(a, copy=True) for a in got]
    with_grids = finish_frame(frame)
    assert with_grids.n_points > 1000
    # the label stage reads the grids, never writes them
    for a, b in zip(prep.grids[("valid", cell)], kept):
        np.testing.assert_array_equal(a, b)
    without = finish_frame(dataclasses.replace(frame, prep=dataclasses.replace(prep, grids={})))
    _same(with_grids, without)
    no_prep = finish_frame(dataclasses.replace(frame, prep=None))
    _same(with_grids, no_prep)
    # a grid on another cell is not taken for the one needed
    other = {(k, c + 1.0): g for (k, c), g in prep.grids.items()}
    _same(with_grids, finish_frame(dataclasses.replace(frame, prep=dataclasses.replace(prep, grids=other))))


def test_fill_gaps_given_the_labelled_positions_equals_finding_them(small_scene_pitch16, monkeypatch):
    s = small_scene_pitch16
    opts = _options(s)
    frame = extract_frame(s.image, s.procam, s.pattern, options=opts)
    calls = {"given": 0}
    orig = labelling._fill_gaps

    def spy(*a, **k):
        if len(a) > 11 and a[11] is not None:
            calls["given"] += 1
            # the positions handed over are the finite-index positions the kernel would find
            sid, index = a[2], a[5]
            np.testing.assert_array_equal(a[11], np.flatnonzero(np.isfinite(index[sid])))
        return orig(*a, **k)

    monkeypatch.setattr(labelling, "_fill_gaps", spy)
    new = finish_frame(frame)
    assert calls["given"] == 1
    assert new.stats["samples_gap_filled"] > 0
    monkeypatch.setattr(labelling, "_fill_gaps", lambda *a, **k: orig(*a[:11], **k))
    old = finish_frame(dataclasses.replace(frame))
    _same(new, old)
    assert new.stats["samples_gap_filled"] == old.stats["samples_gap_filled"]
