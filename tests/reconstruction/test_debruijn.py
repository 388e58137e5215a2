"""De Bruijn sequences and De Bruijn-spaced line offsets (reconstruction/debruijn.py)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from reconstruction.debruijn import (
    debruijn_offsets_px,
    debruijn_order,
    debruijn_sequence,
    debruijn_symbols,
    spacing_values_px,
)
from reconstruction.patterns import GridPattern


def _windows(seq, n: int, *, cyclic: bool) -> list[tuple]:
    s = list(seq) + (list(seq[: n - 1]) if cyclic else [])
    return [tuple(s[i : i + n]) for i in range(len(s) - n + 1)]


@pytest.mark.parametrize("k, n", [(2, 1), (2, 3), (2, 6), (3, 2), (3, 4), (4, 3), (5, 3)])
def test_sequence_holds_every_word_exactly_once(k, n):
    seq = debruijn_sequence(k, n)
    assert seq.shape == (k**n,)
    assert set(seq.tolist()) == set(range(k))
    windows = _windows(seq, n, cyclic=True)
    assert len(set(windows)) == len(windows) == k**n
    assert set(windows) == set(itertools.product(range(k), repeat=n))


def test_known_sequences():
    assert "".join(map(str, debruijn_sequence(2, 3))) == "00010111"
    assert "".join(map(str, debruijn_sequence(3, 2))) == "001021122"
    with pytest.raises(ValueError, match="k >= 2"):
        debruijn_sequence(1, 3)


@pytest.mark.parametrize("lines", [2, 3, 5, 10, 11, 28, 33, 41, 65, 82])
def test_offsets_monotone_centred_and_windows_unique(lines):
    pitch = 30.0
    off = debruijn_offsets_px(lines, pitch)
    assert off.shape == (lines,)
    h = (lines - 1) // 2
    assert off[h] == 0.0, "index 0 (array position (lines-1)//2, as GridPattern.indices) is at 0"
    np.testing.assert_array_equal(GridPattern(lines=lines).indices[h], 0)
    spacing = np.diff(off)
    assert np.all(spacing > 0), "strictly increasing"
    values = spacing_values_px(pitch)
    np.testing.assert_allclose(values, [22.5, 30.0, 37.5])
    symbols = np.argmin(np.abs(spacing[:, None] - values[None, :]), axis=1)
    np.testing.assert_allclose(spacing, values[symbols], atol=1e-9)
    n = debruijn_order(lines, 3)
    windows = _windows(symbols, n, cyclic=False)
    assert len(set(windows)) == len(windows), f"a run of {n} spacings repeats"
    np.testing.assert_array_equal(symbols, debruijn_symbols(lines))
    # Never wider than the uniform grid on either side, so it fits wherever the uniform grid fits.
    assert off[0] >= -h * pitch - 1e-9 and off[-1] <= (lines - 1 - h) * pitch + 1e-9
    if lines >= 10:
        # ... and not much narrower: the spacings are used about evenly.
        assert off[-1] - off[0] > 0.9 * (lines - 1) * pitch


def test_the_default_pattern_is_not_periodic():
    # The point of the spacing: no shift of the labels by s lines maps the offsets onto themselves
    # (for a uniform grid every shift does, up to a constant).
    off = debruijn_offsets_px(33, 30.0)
    spacing = np.diff(off)
    n = debruijn_order(33, 3)
    for s in range(1, 8):
        runs_equal = [np.allclose(spacing[a : a + n], spacing[a + s : a + s + n]) for a in range(len(spacing) - n - s + 1)]
        assert not any(runs_equal), f"a shift of {s} lines leaves a run of {n} spacings unchanged"


def test_options_and_errors():
    off = debruijn_offsets_px(20, 10.0, k=4, spread=0.3)
    np.testing.assert_allclose(np.unique(np.round(np.diff(off), 9)), [7.0, 9.0, 11.0, 13.0])
    with pytest.raises(ValueError, match="too few"):
        debruijn_offsets_px(40, 10.0, k=3, n=3)  # 27 windows for 39 spacings
    with pytest.raises(ValueError, match="spread"):
        debruijn_offsets_px(10, 10.0, spread=1.0)


@pytest.mark.parametrize("width, height", [(1024, 1024), (1920, 1080)])
def test_default_debruijn_grid_stays_within_the_projector(monkeypatch, width, height):
    """GridPattern's own fits() and render() with De Bruijn offsets, for projectors where the uniform grid fits."""
    pattern = GridPattern(centre_px=((width - 1) / 2, (height - 1) / 2))
    assert pattern.fits(width, height) is None
    expected = debruijn_offsets_px(pattern.lines, pattern.pitch_px)
    monkeypatch.setattr(GridPattern, "offsets_px", lambda self, family: expected)
    assert pattern.fits(width, height) is None
    img = pattern.render(width, height)
    # The outermost junctions are drawn inside the image and nothing is lit near its border.
    ii, jj = np.meshgrid(pattern.indices, pattern.indices, indexing="ij")
    uv = pattern.junction_uv(ii.ravel(), jj.ravel())
    assert uv[:, 0].min() > 0 and uv[:, 0].max() < width - 1 and uv[:, 1].min() > 0 and uv[:, 1].max() < height - 1
    corner = uv[np.argmin(uv[:, 1])]
    assert img[int(round(corner[1])), int(round(corner[0]))] > 128


def test_grid_pattern_uses_these_offsets_once_wired():
    """GridPattern(spacing="debruijn") must give exactly these offsets (skips while it still ignores the option)."""
    pattern = GridPattern(spacing="debruijn")
    got = pattern.offsets_px(1)
    if np.allclose(got, pattern.indices * pattern.pitch_px):
        pytest.skip("GridPattern.offsets_px ignores spacing='debruijn' (not wired to reconstruction.debruijn yet)")
    np.testing.assert_allclose(got, debruijn_offsets_px(pattern.lines, pattern.pitch_px))
    np.testing.assert_allclose(pattern.offsets_px(2), got)
