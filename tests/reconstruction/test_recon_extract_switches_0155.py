"""Decision 0155: the extraction's exact speed switches change no output. A rendered 640×480 grid (8-bit, width a
multiple of 16: the fused ring walk runs) is extracted with the int16 lookup grids on and off (also with the int16
limit lowered so that the int32 fallbacks run) and with the ring walk on and off; every GridObservation array equal."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam
from reconstruction import extraction
from reconstruction.extraction import ExtractOptions, extract_grid
from reconstruction.patterns import GridPattern
from reconstruction.rigmodel import rig_model


def _frame():
    K = np.array([[800.0, 0, 319.5], [0, 800.0, 239.5], [0, 0, 1]])
    dev = Intrinsics(640, 480, K)
    procam = ProCam(dev, dev, np.eye(3), np.array([1.0, 0.5, 0.0]))
    pattern = GridPattern(alpha1_deg=35.0, alpha2_deg=125.0, pitch_px=14.0, lines=41, line_width_px=1.5,
                          centre_px=(320.3, 240.7))
    model = rig_model(procam, pattern, (900.0, 1100.0))
    img = pattern.render(640, 480).astype(np.float32) / 255 * 200 + 10
    img[300:480, 400:640] *= 0.4  # a darker patch: uneven albedo, free ends and T's at its border
    img += np.random.default_rng(3).normal(0, 2.0, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8), model


def _arrays(obs) -> dict:
    out = {}
    for f in dataclasses.fields(obs):
        v = getattr(obs, f.name)
        if isinstance(v, np.ndarray):
            out[f.name] = v
    st = {k: v for k, v in obs.stats.items() if k != "ms"}
    return out, st


def _equal(a, b):
    (xa, sa), (xb, sb) = a, b
    assert xa.keys() == xb.keys()
    for k in xa:
        assert xa[k].dtype == xb[k].dtype, k
        np.testing.assert_array_equal(xa[k], xb[k], err_msg=k)
    assert sa == sb


@pytest.mark.parametrize("switch, values", [("_GRID_NARROW", (True, False)), ("_RING_WALK", (True, False)),
                                            ("_INT16_IDS", (32767, 50, 1))])
def test_extraction_outputs_do_not_depend_on_the_speed_switches(monkeypatch, switch, values):
    img, model = _frame()
    res = []
    for v in values:
        monkeypatch.setattr(extraction, switch, v)
        obs = extract_grid(img, model, options=ExtractOptions())
        res.append(_arrays(obs))
    assert len(res[0][0]["q"]) > 1000 and len(res[0][0]["q_junction"]) > 50
    for r in res[1:]:
        _equal(res[0], r)
