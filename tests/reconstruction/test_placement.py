"""The labelling margin: exact degeneracies of the 30°/120° grid, and what the working volume rules out."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.models import Intrinsics, ProCam, look_at
from reconstruction.patterns import GridPattern
from reconstruction.placement import labelling_margin

CAM = Intrinsics(640, 512, [[1150.0, 0, 319.5], [0, 1150.0, 255.5], [0, 0, 1]])
PROJ = Intrinsics(1024, 1024, [[2400.0, 0, 511.5], [0, 2400.0, 511.5], [0, 0, 1]])
GRID = GridPattern()


def _rig(angle_deg: float, baseline_mm: float = 300.0) -> ProCam:
    a = np.deg2rad(angle_deg)
    t = baseline_mm * np.array([np.cos(a), -np.sin(a), 0.0])
    return ProCam(CAM, PROJ, look_at(t, np.array([0.0, 0.0, 900.0])), t)


def test_horizontal_baseline_is_exactly_degenerate():
    # With epipolar lines parallel to x, junction (i+1, j-3) sits on (i, j)'s epipolar line: n2·1 − n1·(−3) = 0.
    m = labelling_margin(_rig(0.0), GRID, depth_range_mm=(750.0, 1050.0))
    assert m.margin_px == pytest.approx(0.0, abs=1e-6)
    assert m.offset is not None and (m.offset[0] * -3 == m.offset[1])
    assert m.verdict == "ill-posed" and "ill-posed" in m.advice()


@pytest.mark.parametrize("angle", [30.0, 90.0])
def test_other_lattice_directions_are_degenerate(angle):
    assert labelling_margin(_rig(angle), GRID, depth_range_mm=(750.0, 1050.0)).margin_px < 1e-6


def test_a_good_direction_has_a_margin():
    m = labelling_margin(_rig(7.5), GRID, depth_range_mm=(750.0, 1050.0))
    assert m.margin_px > 1.0 and m.verdict == "good"


def test_a_thin_working_volume_rules_every_wrong_label_out():
    wide = labelling_margin(_rig(0.0), GRID, depth_range_mm=(500.0, 2000.0))
    thin = labelling_margin(_rig(0.0), GRID, depth_range_mm=(899.0, 901.0))
    assert wide.margin_px == pytest.approx(0.0, abs=1e-6)
    # Only labels whose surface would lie in the thin volume remain: none of them near the epipolar line.
    assert thin.margin_px > 5.0 and thin.verdict == "good"
