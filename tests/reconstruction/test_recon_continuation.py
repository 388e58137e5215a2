"""Continuation of labelled lines across crossings without labelled junctions (reconstruction.continuation,
decision 0066), against simulator truth."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.extraction import extract_grid, sigma_for, ExtractOptions
from reconstruction.labelling import LabelOptions, TraceOptions, label_epipolar, label_samples
from reconstruction.rigmodel import UNLABELLED, rig_model
from tests.reconstruction._truth import true_index


#: the extraction these scenarios were measured with: without decision 0120's shared arms, which find junctions in
#: the compressed bands whose labelling by the later steps these tests exercise (their counts are measured on it),
#: and without decision 0129's crossing candidates (more junctions there too: test_label_speed4_cross_rounds' labels
#: then reach the disc's centre in 3 writing rounds instead of the 4 it needs), nor decision 0133's acute re-centring
#: (a few more junctions: test_recon_cross_after_continuation's round then labels 19 new samples, its floor is 20)
SCENARIO_EXTRACT = ExtractOptions(shared_arms=False, crossing_eigen_noise=False, merge_close_candidates=False, acute_recentre=False)


def _stage(s):
    model = rig_model(s.procam, s.pattern, s.depth_range_mm)
    obs = extract_grid(s.image, model, options=SCENARIO_EXTRACT)
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction),
                         options=LabelOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1]))
    return model, obs, lab


def _samples(s, model, obs, labels, **trace):
    # the continuation measured on its own: decision 0089's piece seeds, decision 0092's piece junctions,
    # decision 0093's surface labels, decision 0103's lines beside labelled lines and decision 0139's lone crossings
    # (after it) off unless asked for
    trace = {"piece_seeds": False, "piece_junctions": False, "surface_labels": False, "beside_lines": False, "lone_crossings": False,
             **trace}
    return label_samples(obs, labels, sigma_px=float(obs.stats.get("sigma_px", sigma_for(model, ExtractOptions()))),
                         seed_radius_px=float(obs.stats["junction_radius_px"]), options=TraceOptions(**trace), model=model,
                         depth_range_mm=s.depth_range_mm, image=s.image, line_width_px=model.line_width_cam_px)


@pytest.fixture(scope="module")
def hole(small_scene):
    """The small scene with the junction labels in a disc of three junction steps taken away (as if
    extraction had found no junctions there): the samples of that disc can be labelled only by carrying
    their lines' indices in from outside."""
    s = small_scene
    model, obs, lab = _stage(s)
    labels = lab.labels.copy()
    ok = labels[:, 0] != UNLABELLED
    centre = np.median(obs.q_junction[ok], axis=0)
    radius = 3.0 * model.junction_step_cam_px
    gone = np.hypot(*(obs.q_junction - centre).T) < radius
    labels[gone] = UNLABELLED
    inside = np.hypot(*(obs.q - centre).T) < radius - 0.5 * model.junction_step_cam_px
    return s, model, obs, labels, inside


def test_lines_are_continued_into_a_patch_without_labelled_junctions_with_their_true_index(hole):
    s, model, obs, labels, inside = hole
    off = _samples(s, model, obs, labels, continue_lines=False)
    on = _samples(s, model, obs, labels)
    n_off = int(np.isfinite(off.index[inside]).sum())
    n_on = int(np.isfinite(on.index[inside]).sum())
    assert inside.sum() > 200
    # without continuation the patch stays mostly dark; with it, most of its line samples are labelled
    assert n_on > n_off + 0.4 * inside.sum(), (n_off, n_on, int(inside.sum()))
    assert on.stats["samples_continued"] > 100
    # every sample that continuation (and the gap filling after it) added is on its true line
    new = np.isfinite(on.index) & ~np.isfinite(off.index)
    true = true_index(s.truth, s.pattern, on.q[new], obs.family[new])
    known = np.isfinite(true)
    assert known.mean() > 0.95
    assert np.max(np.abs(true[known] - on.index[new][known])) < 0.3


def test_a_wrong_index_fails_the_crossing_check_at_the_pieces_ends(hole):
    # Shift every i label by one (the j labels stay right): the continued i-line pieces would carry a wrong
    # index, and their crossings, triangulated on the wrong light sheet, miss the j-lines; the j-line pieces
    # still pass.
    s, model, obs, labels, inside = hole
    shifted = labels.copy()
    ok = shifted[:, 0] != UNLABELLED
    shifted[ok, 0] += 1

    def continued(lab, f, **trace):
        # the continuation alone: the crossing round after it (decision 0074) labels i-line pieces from the
        # right j-lines with their own, true index (45 samples here, all right), which this count would take
        # for continued wrong ones
        base = _samples(s, model, obs, lab, continue_lines=False)
        res = _samples(s, model, obs, lab, cross_rounds_after=0, **trace)
        return int((np.isfinite(res.index) & ~np.isfinite(base.index) & (obs.family == f)).sum())

    right_1, right_2 = continued(labels, 1), continued(labels, 2)
    assert right_1 > 40 and right_2 > 40  # (47 and 336 with the extraction of decision 0068)
    # without the check (any crossing residual accepted) the wrong i index is carried as far as the right one
    assert continued(shifted, 1, continue_tol_px=1e9) > 0.8 * right_1
    # with it, a piece passes only by chance (both its crossings landing near a j-line on the wrong sheet)
    assert continued(shifted, 1) < 0.2 * right_1, (continued(shifted, 1), right_1)
    assert continued(shifted, 2) > 0.5 * right_2
