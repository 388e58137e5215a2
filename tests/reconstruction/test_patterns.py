"""The projected grid: junction geometry (the paper's Eq. 1) and the rendered image."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.patterns import GridPattern


def test_junctions_lie_on_both_lines():
    g = GridPattern(alpha1_deg=25.0, alpha2_deg=110.0, pitch_px=24.0, lines=11)
    ii, jj = np.meshgrid(g.indices, g.indices, indexing="ij")
    xy = g.junction_xy(ii.ravel(), jj.ravel())
    np.testing.assert_allclose(xy[:, 1], g.n1 * xy[:, 0] + ii.ravel() * g.pitch_px, atol=1e-9)
    np.testing.assert_allclose(xy[:, 1], g.n2 * xy[:, 0] + jj.ravel() * g.pitch_px, atol=1e-9)


def test_indices_are_centred():
    assert GridPattern(lines=33).indices.tolist() == list(range(-16, 17))
    assert len(GridPattern(lines=4).indices) == 4


def test_render_lines_at_the_right_place():
    g = GridPattern()
    img = g.render(1024, 1024)
    uv = g.junction_uv(np.array([0, 5, -7]), np.array([0, -3, 2]))
    for u, v in uv:
        assert img[int(round(v)), int(round(u))] >= 200
    # Midway between two neighbouring i-lines (and away from j-lines) it is dark.
    x = 0.0
    j_mid = g.junction_xy(np.array([0.5]), np.array([0.5]))[0]
    assert img[int(round(j_mid[1] + 511.5)), int(round(j_mid[0] + 511.5))] == 0
    # Outside the parallelogram of crossings, nothing is drawn.
    assert img[5, 5] == 0 and img[1018, 1018] == 0
    assert x == 0.0


def test_line_profile_is_symmetric_and_has_its_width():
    g = GridPattern(alpha1_deg=0.0001, alpha2_deg=60.0, pitch_px=40.0, lines=5, line_width_px=3.0, centre_px=(100.0, 100.0))
    img = g.render(200, 200).astype(float)
    col = img[:, 60]  # crosses the i-lines (nearly horizontal) at v = 100 + 40 i
    profile = col[95:106]
    assert profile.sum() / 255 == pytest.approx(3.0, abs=0.05)
    centre = (np.arange(95, 106) * profile).sum() / profile.sum()
    assert centre == pytest.approx(100.0, abs=0.02)


def test_fits_names_the_fix():
    assert GridPattern().fits(1024, 1024) is None
    msg = GridPattern().fits(1024, 768)
    assert msg is not None and "outside the 1024x768 projector" in msg and "pitch_px" in msg


def test_debruijn_spacing_keeps_junctions_on_their_lines():
    g = GridPattern(spacing="debruijn")
    c1, c2 = g.offsets_px(1), g.offsets_px(2)
    steps = np.diff(c1)
    assert len(set(np.round(steps, 6))) == 3 and (steps > 0).all(), "three spacings, increasing offsets"
    assert c1[(g.lines - 1) // 2] == 0.0
    ii, jj = np.meshgrid(g.indices, g.indices, indexing="ij")
    xy = g.junction_xy(ii.ravel(), jj.ravel())
    np.testing.assert_allclose(xy[:, 1], g.n1 * xy[:, 0] + c1[ii.ravel() - g.indices[0]], atol=1e-9)
    np.testing.assert_allclose(xy[:, 1], g.n2 * xy[:, 0] + c2[jj.ravel() - g.indices[0]], atol=1e-9)
    assert g.fits(1024, 1024) is None
