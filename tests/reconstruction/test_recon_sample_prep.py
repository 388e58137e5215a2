"""Decision 0107: the label stage's measurements that need no label (`labelling.prepare_samples`) run in the
extraction stage. The labels must not change, and a prep computed for other samples, options or another image
is refused rather than used."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from reconstruction.labelling import TraceOptions, label_epipolar, label_samples, prepare_samples
from reconstruction.pipeline import ReconstructOptions, extract_frame, finish_frame, reconstruct


def _options(s) -> ReconstructOptions:
    return ReconstructOptions(depth_min_mm=s.depth_range_mm[0], depth_max_mm=s.depth_range_mm[1])


def _inputs(s):
    frame = extract_frame(s.image, s.procam, s.pattern, options=_options(s))
    obs, model = frame.obs, frame.model
    lab = label_epipolar(obs, model, model.cam_normalised(obs.q_junction))
    kw = dict(sigma_px=float(obs.stats["sigma_px"]), seed_radius_px=float(obs.stats["junction_radius_px"]), model=model,
              depth_range_mm=s.depth_range_mm, image=s.image, line_width_px=model.line_width_cam_px)
    return frame, obs, lab, kw


def test_the_extraction_stage_prepares_the_samples_and_the_labels_do_not_change(small_scene_pitch16):
    s = small_scene_pitch16
    frame, obs, lab, kw = _inputs(s)
    assert frame.prep is not None and frame.prep.n_valid > 0.9 * len(obs.q)
    assert frame.prep.near_other.sum() > 0 and frame.prep.ridge.shape == (len(obs.q),)
    assert frame.xy_cam_j.shape == (len(obs.q_junction), 2)
    a = label_samples(obs, lab.labels, **kw)  # prep computed inside
    b = label_samples(obs, lab.labels, **kw, prep=prepare_samples(obs, sigma_px=kw["sigma_px"], image=s.image))
    assert np.isfinite(a.index).sum() > 0.5 * len(obs.q)
    np.testing.assert_array_equal(a.index, b.index)
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.junction, b.junction)
    # the pipeline's two stages (prep from the first) give what one call gives without a frame's prep
    r1 = finish_frame(frame)
    r2 = finish_frame(dataclasses.replace(frame, prep=None, xy_cam_j=None))
    np.testing.assert_array_equal(r1.points_proj, r2.points_proj)
    np.testing.assert_array_equal(r1.points_proj, reconstruct(s.image, s.procam, s.pattern, options=_options(s)).points_proj)


def test_a_prep_for_other_samples_options_or_image_is_refused(small_scene_pitch16):
    s = small_scene_pitch16
    _frame, obs, lab, kw = _inputs(s)
    prep = prepare_samples(obs, sigma_px=kw["sigma_px"], image=s.image)
    with pytest.raises(ValueError, match="prep was computed for"):
        label_samples(obs, lab.labels, **kw, options=TraceOptions(mix_sigma=3.0), prep=prep)
    with pytest.raises(ValueError, match="prep was computed for"):
        label_samples(obs, lab.labels, **{**kw, "sigma_px": kw["sigma_px"] + 0.5}, prep=prep)
    with pytest.raises(ValueError, match="prep was computed for"):
        label_samples(obs, lab.labels, **{**kw, "image": s.image.copy()}, prep=prep)
