"""Decision 0142: the lone-crossings step (decision 0139) compiled. Its outputs (index, seeds, counts) must equal, to
the bit, those of the NumPy code it replaced (kept as `_lone_crossings_reference.py`, the module as 0139 merged it),
on the step's real inputs (the small scene with every junction label taken away: thousands of samples, dozens of
nodes, far-end checks) under several options; and the kernels' NumPy fallbacks (debug, pixels off the camera table)
must give the same."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import reconstruction.labelling as labelling
import reconstruction.lone_crossings as lc
from reconstruction.rigmodel import UNLABELLED
from tests.reconstruction import _lone_crossings_reference as ref


@pytest.fixture(scope="module")
def step_inputs(small_scene, small_scene_pitch16):
    """The step's arguments as label_samples passes them: the small scenes with every junction label taken away and
    the other label-free steps off (the step then labels thousands of samples), and the full pipeline's on pitch 16."""
    from reconstruction.extraction import ExtractOptions, extract_grid, sigma_for
    from reconstruction.labelling import TraceOptions, label_samples
    from reconstruction.pipeline import ReconstructOptions, reconstruct
    from reconstruction.rigmodel import rig_model

    calls = []
    real = labelling.label_lone_crossings

    def spy(*a, **k):
        calls.append(([np.copy(x) if isinstance(x, np.ndarray) else x for x in a],
                      {key: (np.copy(v) if isinstance(v, np.ndarray) else v) for key, v in k.items()}))
        return real(*a, **k)

    alone = dict(continue_lines=False, piece_seeds=False, piece_junctions=False, cross_rounds=0, cross_rounds_after=0,
                 beside_lines_ends=False, surface_labels=False, beside_lines=False, depth_range_labels=False)
    mp = pytest.MonkeyPatch()
    mp.setattr(labelling, "label_lone_crossings", spy)
    try:
        for s in (small_scene, small_scene_pitch16):
            model = rig_model(s.procam, s.pattern, s.depth_range_mm)
            obs = extract_grid(s.image, model, options=ExtractOptions())
            labels = np.full((len(obs.q_junction), 2), UNLABELLED, np.int64)
            sigma = float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions())))
            label_samples(obs, labels, sigma_px=sigma, seed_radius_px=float(obs.stats["junction_radius_px"]),
                          options=TraceOptions(**alone, lone_crossings=True), model=model,
                          depth_range_mm=s.depth_range_mm, image=s.image, line_width_px=model.line_width_cam_px)
        s = small_scene_pitch16
        reconstruct(s.image, s.procam, s.pattern,
                    options=ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1]))
    finally:
        mp.undo()
    assert len(calls) == 3
    return calls


def _run(fn, call, options=None, seed=True, **extra):
    (q, fam, sid, piece, ts, index), kw = call
    kw = dict(kw)
    if options is not None:
        kw["options"] = options
    kw["seed"] = np.copy(kw["seed"]) if (seed and kw.get("seed") is not None) else None
    kw.pop("ridge", None)  # without the ridge, decision 0164's step 6b is off: the step as 0139 / 0142 made it
    index = np.copy(index)
    stats = fn(q, fam, sid, piece, ts, index, **kw, **extra)
    return stats, index, kw["seed"]


def _same(a, b):
    (sa, ia, ka), (sb, ib, kb) = a, b
    assert sa == sb
    assert np.array_equal(ia, ib, equal_nan=True)
    assert (ka is None) == (kb is None)
    if ka is not None:
        assert np.array_equal(ka, kb)


VARIANTS = [dict(), dict(t_nodes=False), dict(far_end_check=False), dict(min_samples=3), dict(merge_share=1.0),
            dict(check_samples=3), dict(min_llr=4.0, min_rms_ratio=1.1), dict(free_end_trim=1.0, node_end_trim=0.0)]


@pytest.mark.parametrize("variant", VARIANTS)
def test_compiled_step_equals_the_numpy_reference(step_inputs, variant):
    labelled = 0
    for call in step_inputs:
        new = _run(lc.label_lone_crossings, call, replace(lc.LoneCrossingOptions(), **variant))
        old = _run(ref.label_lone_crossings, call, replace(ref.LoneCrossingOptions(), **variant))
        _same(new, old)
        labelled += new[0]["samples"]
    if not variant:
        assert labelled > 1000  # the inputs exercise the step: many nodes accepted, pieces labelled


def test_inputs_reach_every_compiled_stage(step_inputs, monkeypatch):
    seen = {}
    for name in ("_k_nodes", "_k_group_samples", "_k_check_choice", "_k_far_ends", "_k_label_pieces"):
        real = getattr(lc, name)

        def spy(*a, _real=real, _name=name):
            out = _real(*a)
            seen.setdefault(_name, []).append(out)
            return out

        monkeypatch.setattr(lc, name, spy)
    stats = [_run(lc.label_lone_crossings, call)[0] for call in step_inputs]
    assert set(seen) == {"_k_nodes", "_k_group_samples", "_k_check_choice", "_k_far_ends", "_k_label_pieces"}
    assert all(out[0] for out in seen["_k_check_choice"]) and all(out[0] for out in seen["_k_group_samples"])
    assert sum(s.get("pieces_far_end", 0) for s in stats) > 0 or any(not out[1].all() for out in seen["_k_far_ends"])
    assert sum(s["nodes"] - s["nodes_labelled"] for s in stats) > 0  # ambiguous nodes too


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # the debug record takes np.cross of 2-vectors (both modules)
def test_without_seed_and_with_debug_the_same(step_inputs):
    for call in step_inputs:
        _same(_run(lc.label_lone_crossings, call, seed=False), _run(ref.label_lone_crossings, call, seed=False))
        # debug takes the NumPy checks and choice (the kernel's reference inside the module)
        d_new, d_old = {}, {}
        _same(_run(lc.label_lone_crossings, call, debug=d_new), _run(ref.label_lone_crossings, call, debug=d_old))
        assert len(d_new["nodes"]) == len(d_old["nodes"])


def test_pixels_off_the_camera_table_take_the_numpy_path(step_inputs, monkeypatch):
    """A pixel outside the camera table makes the kernels hand back (False): the NumPy path then gives the same."""
    real = lc._k_cam_bilinear

    @lc.njit(cache=False)
    def _outside(q, tab, inv_step, out, inside):
        real(q, tab, inv_step, out, inside)
        inside[0] = False

    monkeypatch.setattr(lc, "_k_cam_bilinear", _outside)
    # the kernels bind _k_cam_bilinear at compile time: call a fresh compilation of _k_group_samples that uses _outside
    monkeypatch.setattr(lc, "_k_group_samples", lc.njit(cache=False)(lc._k_group_samples.py_func))
    seen = []
    real_gs = lc._k_group_samples

    def spy(*a):
        out = real_gs(*a)
        seen.append(out[0])
        return out

    monkeypatch.setattr(lc, "_k_group_samples", spy)
    for call in step_inputs:
        _same(_run(lc.label_lone_crossings, call), _run(ref.label_lone_crossings, call))
    assert seen and not any(seen)


def test_open_pieces_kernel_against_numpy():
    rng = np.random.default_rng(5)
    for _ in range(50):
        n = int(rng.integers(1, 300))
        piece = np.sort(rng.integers(0, max(1, n // 4), n))
        piece = np.unique(piece, return_inverse=True)[1].astype(np.int64)
        P = n + 10
        sid = rng.permutation(P)[:n].astype(np.int64)
        index = np.where(rng.random(P) < 0.2, rng.integers(-5, 5, P).astype(np.float64), np.nan)
        starts, stops, open_mask = lc._k_open_pieces(piece, sid, index, 4)
        s_ref = np.flatnonzero(np.r_[True, piece[1:] != piece[:-1]])
        e_ref = np.r_[s_ref[1:], n]
        n_lab = np.bincount(piece, np.isfinite(index[sid]), len(s_ref))
        assert np.array_equal(starts, s_ref) and np.array_equal(stops, e_ref)
        assert np.array_equal(open_mask, (n_lab == 0) & (e_ref - s_ref >= 4))


def test_far_end_kernel_equals_the_full_one(step_inputs):
    """_k_far_ends (end lines fitted where read, ends that cannot reach X skipped unfitted) against
    _k_free_end_crossings over every long piece's end line, for every unlabelled piece end as a free end."""
    checked = 0
    for (q, fam, sid, piece, ts, index), kw in step_inputs:
        starts, stops, open_mask = lc._k_open_pieces(piece, sid, index, 4)
        trim = float(kw["trim_px"])
        long_mask = stops - starts >= 4
        e_pt, e_dir, e_rms, e_end, ok_all = lc._k_end_lines(q, sid, ts, starts, stops, long_mask, trim)
        n_p = len(starts)
        e_piece = np.arange(2 * n_p, dtype=np.int64) // 2
        e_fam = np.asarray(fam[sid[starts]], np.int64)[e_piece]
        free = np.flatnonzero(ok_all & np.repeat(open_mask, 2)).astype(np.int64)
        args = (float(kw["reach_px"]), float(kw["lateral_px"]), 3.0, float(np.cos(np.deg2rad(25.0))), float(np.sin(np.deg2rad(10.0))))
        X0, ok0 = ref._k_free_end_crossings(free, e_fam, ok_all, e_piece, e_pt, e_dir, e_end, *args)
        p1, d1, r1, en1, k1 = lc._k_end_lines(q, sid, ts, starts, stops, open_mask, trim)
        X1, ok1, on1 = lc._k_far_ends(free, e_fam, e_piece, q, sid, ts, starts, stops, long_mask, np.repeat(open_mask, 2), p1, d1, r1, en1,
                                      k1, trim, *args, False)
        assert np.array_equal(X0, X1, equal_nan=True) and np.array_equal(ok0, ok1)
        # decision 0164: with own_line the verdict is the same, and "goes on" is also read where the other line runs through
        X2, ok2, on2 = lc._k_far_ends(free, e_fam, e_piece, q, sid, ts, starts, stops, long_mask, np.repeat(open_mask, 2), p1, d1, r1, en1,
                                      k1, trim, *args, True)
        assert np.array_equal(X1, X2, equal_nan=True) and np.array_equal(ok1, ok2)
        assert np.all(on2[on1]) and not np.any(on2 & ~ok2)
        checked += int(np.isfinite(X0[:, 0]).sum())
    assert checked > 20
