"""Continuation across crossings whose gap is longer than the reach a junction step gives (decision 0072):
a dense grid (pitch 16 projector px) on the small rig, where the junction step in the camera (~7 px) is
shorter than the gap a crossing leaves in a trace (~2·3σ·√2 with σ ≈ 1.1 px), against simulator truth."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from reconstruction._continuation_kernels import facing_links
from reconstruction._link_kernels import facing_links_mid
from reconstruction.continuation import crossing_gap_px
from reconstruction.rigmodel import UNLABELLED
from tests.reconstruction._truth import true_index

# the helpers of the continuation test (stages, label_samples with options, the true line index)
_spec = importlib.util.spec_from_file_location("_cont_helpers", Path(__file__).with_name("test_recon_continuation.py"))
_h = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_h)


@pytest.fixture(scope="module")
def dense_hole(small_scene_pitch16):
    """The small rig and scene shown a grid of pitch 16, junction labels in a disc of three junction steps
    taken away (as if extraction had found none there)."""
    s = small_scene_pitch16
    model, obs, lab = _h._stage(s)
    labels = lab.labels.copy()
    ok = labels[:, 0] != UNLABELLED
    centre = np.median(obs.q_junction[ok], axis=0)
    radius = 3.0 * model.junction_step_cam_px
    labels[np.hypot(*(obs.q_junction - centre).T) < radius] = UNLABELLED
    inside = np.hypot(*(obs.q - centre).T) < radius - 0.5 * model.junction_step_cam_px
    return s, model, obs, labels, inside


def test_the_gap_outgrows_the_junction_step_on_this_rig(dense_hole):
    s, model, obs, labels, inside = dense_hole
    gap = crossing_gap_px(obs.stats["sigma_px"], mix_sigma=2.0, trim_sigma=1.0, min_angle_deg=45.0)
    assert 0.6 * model.junction_step_cam_px < 6.0 < gap


def test_lines_are_continued_across_gaps_longer_than_the_junction_step_with_their_true_index(dense_hole):
    s, model, obs, labels, inside = dense_hole
    old = _h._samples(s, model, obs, labels, continue_gap_deg=0.0)  # reach from the junction step only (0066)
    new = _h._samples(s, model, obs, labels)
    n_old = int(np.isfinite(old.index[inside]).sum())
    n_new = int(np.isfinite(new.index[inside]).sum())
    assert inside.sum() > 150
    # with the junction step's reach the patch stays mostly dark (no link across a crossing's gap); with the
    # gap's reach most of its samples are labelled (measured: 24 and 146 of 180)
    assert n_old < 0.25 * inside.sum(), (n_old, int(inside.sum()))
    assert n_new > n_old + 0.5 * inside.sum(), (n_old, n_new, int(inside.sum()))
    # every sample labelled in the patch is on its true line
    got = np.isfinite(new.index) & inside
    true = true_index(s.truth, s.pattern, new.q[got], obs.family[got])
    known = np.isfinite(true)
    assert known.mean() > 0.95
    assert np.max(np.abs(true[known] - new.index[got][known])) < 0.3


@pytest.mark.parametrize("column, shift", [(0, 1), (0, -1), (1, 1), (1, -1)])
def test_a_wrong_index_is_mostly_rejected_by_the_crossing_check(dense_hole, column, shift):
    # Shift every label of one family by one: continued pieces of that family would carry a wrong index.
    # Without the crossing check they are carried nearly as far as the right ones; with it, a wrong piece
    # passes only where its crossings, triangulated on the wrong light sheet, happen to land within 1
    # projector px of a line of the other family (a quarter or less of them on this rig; measured: 24, 17,
    # 10 and 0 wrong samples against 96, 130, 1528 and 1528 without the check).
    s, model, obs, labels, inside = dense_hole
    family = column + 1
    shifted = labels.copy()
    shifted[shifted[:, 0] != UNLABELLED, column] += shift
    base = _h._samples(s, model, obs, shifted, continue_lines=False)

    def wrong(**trace) -> int:
        res = _h._samples(s, model, obs, shifted, **trace)
        new = np.isfinite(res.index) & ~np.isfinite(base.index) & (obs.family == family)
        true = true_index(s.truth, s.pattern, res.q[new], obs.family[new])
        return int((np.abs(true - res.index[new]) > 0.3).sum())

    unchecked = wrong(continue_tol_px=1e9)
    assert unchecked > 80
    assert wrong() <= 0.3 * unchecked, (wrong(), unchecked)


def test_midpoint_test_links_a_curved_line_and_rejects_a_sideways_step():
    # One circular line (radius 60 px) cut by a 9 px gap, and the same line shifted 1.5 px sideways beyond
    # the gap (a depth edge). The per-end test of 0066 measures the other end against each end's tangent:
    # on the arc that is r·(1 − cos(g/r)) ≈ g²/(2r) = 0.7 px plus the chord's direction error; the test at
    # the gap's middle compares the two tangents' extrapolations, which meet on an arc.
    r = 60.0
    g = 9.0
    a0 = -g / (2 * r)
    a1 = g / (2 * r)

    def ends(shift: float):
        # piece 0 ends at angle a0 going clockwise, piece 1 starts at a1; outward directions along the arc
        e = np.array([[0.0, 0.0], [r * np.sin(a0), r - r * np.cos(a0)], [r * np.sin(a1), r - r * np.cos(a1) + shift], [0.0, 0.0]])
        u = np.array([[1.0, 0.0], [np.cos(a0), np.sin(a0)], [-np.cos(a1), -np.sin(a1)], [1.0, 0.0]])
        # rows: piece 0 first end, piece 1 first end, piece 0 last end, piece 1 last end (n_p = 2)
        e_rows = np.array([e[0] - [30, 0], e[2], e[1], e[3] + [90, 0]])
        u_rows = np.array([-u[0], u[2], u[1], u[3]])
        return np.ascontiguousarray(e_rows), np.ascontiguousarray(u_rows)

    fam = np.array([1, 1, 1, 1], np.int64)
    lab = np.array([True, False])
    cos12 = float(np.cos(np.deg2rad(12.0)))
    e, u = ends(0.0)
    assert len(facing_links_mid(e, u, fam, 2, lab, 12.0, 0.5, cos12)[0]) == 1
    e, u = ends(1.5)
    assert len(facing_links_mid(e, u, fam, 2, lab, 12.0, 1.0, cos12)[0]) == 0
    # the per-end test (0066) rejects the arc at the same limit: the far end is g²/(2r) ≈ 0.7 px off each tangent
    e, u = ends(0.0)
    assert len(facing_links(e, u, fam, 2, lab, 12.0, 0.5, cos12)[0]) == 0
