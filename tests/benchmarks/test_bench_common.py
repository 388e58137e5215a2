"""benchmarks/_common.py: the pieces every benchmark's figures rest on (truth sampling, coverage, tables).

benchmarks/ is not an installed package, so the module is loaded from its file."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import numpy as np
import pytest

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "_common.py"


@pytest.fixture(scope="module")
def common():
    name = "bench_common_under_test"
    spec = importlib.util.spec_from_file_location(name, _PATH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up there
    try:
        spec.loader.exec_module(mod)
        yield mod
    finally:
        del sys.modules[name]


def test_sample_bilinear_is_exact_on_a_linear_image_and_nan_outside(common):
    # a(v, u) = 3u − 2v + 7 (and a second channel 0.5u + v): bilinear interpolation reproduces it up to
    # OpenCV's 1/32-pixel map quantisation (slope ≤ 3 grey per px → error ≤ 3 · (1/64) per axis).
    H, W = 40, 50
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    a = np.stack([3 * u - 2 * v + 7, 0.5 * u + v], axis=-1)
    rng = np.random.default_rng(3)
    n = 40_000  # more than OpenCV's 32767-row limit for one map column
    # (the last row and column stay out: a point there interpolates with the NaN border)
    q = np.column_stack([rng.uniform(0, W - 2, n), rng.uniform(0, H - 2, n)])
    out = common.sample_bilinear(a, q)
    assert out.shape == (n, 2) and out.dtype == np.float64
    truth = np.column_stack([3 * q[:, 0] - 2 * q[:, 1] + 7, 0.5 * q[:, 0] + q[:, 1]])
    assert np.abs(out - truth).max() <= 5 * (1 / 64) + 1e-4
    outside = common.sample_bilinear(a[..., 0], np.array([[-3.0, 5.0], [10.0, H + 2.0], [10.0, 10.0]]), dtype=np.float32)
    assert outside.dtype == np.float32 and outside.shape == (3, 1)
    assert np.isnan(outside[:2]).all() and outside[2, 0] == pytest.approx(3 * 10 - 2 * 10 + 7)
    assert common.sample_bilinear(a, np.zeros((0, 2))).shape == (0, 2)


def test_covered_share_counts_target_pixels_within_the_radius(common):
    target = np.zeros((20, 30), bool)
    target[10, 5:25] = True  # a 20-pixel line
    q = np.array([[5.2, 10.4]])  # rounds to pixel (u=5, v=10): covers u = 5, 6 (distance ≤ 1.5), not 7
    assert common.covered_share(target, q, radius_px=1.5) == pytest.approx(2 / 20)
    assert common.covered_share(target, np.zeros((0, 2)), radius_px=1.5) == 0.0
    assert np.isnan(common.covered_share(np.zeros((5, 5), bool), q))


def test_markdown_table_lines_and_alignment(common):
    lines = common.markdown_table(["a", "b c"], [["1", ""], ["x", "2.50"]], align="lr")
    assert lines == ["| a | b c |", "|---|---:|", "| 1 |  |", "| x | 2.50 |"]
    with pytest.raises(ValueError, match="one per column"):
        common.markdown_table(["a", "b"], [], align="l")


def test_fmt_and_write_markdown(common, tmp_path):
    assert common.fmt(float("nan")) == "–" and common.fmt(1.23456, 3) == "1.235" and common.fmt(2.0, 0) == "2"
    path = tmp_path / "deeper" / "t.md"
    common.write_markdown(path, ["# t", "| é |", ""])
    assert path.read_bytes() == "# t\n| é |\n".encode()


def test_tree_state_names_the_commit(common):
    state = common.tree_state(["benchmarks/_common.py"])
    assert state == "unknown (no git)" or re.fullmatch(r"commit [0-9a-f]{4,}, (clean|with uncommitted changes to .+)", state)


@pytest.mark.parametrize("stretch", [1.0, 0.25])
def test_line_centre_pixels_are_one_camera_pixel_wide_across_each_line(common, stretch):
    """The coverage target is the band within half a camera pixel of each line's centre, measured across the line
    (decision 0101). On an affine projector map q = A·(u, v) + c, the camera distance of a pixel to a line of family
    f is |s_f − offset| / |∇s_f| exactly. With the map foreshortened along one image axis (stretch 0.25: one
    projector px spans 4 camera px there), a scale taken from the map's larger axis instead would widen the band
    of the lines that run across the foreshortened axis to several camera px."""
    from types import SimpleNamespace

    from reconstruction.patterns import GridPattern

    H = W = 240
    pat = GridPattern(pitch_px=12.0, lines=61, line_width_px=2.0, centre_px=(100.0, 60.0))  # drawn over the whole image
    A = np.array([[0.8, 0.0], [0.0, 0.8 * stretch]]) @ np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    q = np.stack([A[0, 0] * uu + A[0, 1] * vv + 10.0, A[1, 0] * uu + A[1, 1] * vv + 5.0], axis=-1)
    truth = SimpleNamespace(q_proj=q.astype(np.float32), lit=np.ones((H, W), bool))
    target = common.line_centre_pixels(truth, pat)
    # the analytic camera distance to the nearest drawn line of each family, and the total drawn length in the image
    dist = np.full((H, W), np.inf)
    x, y = q[..., 0] - pat.centre_px[0], q[..., 1] - pat.centre_px[1]
    length = 0.0
    for fam, n in ((1, pat.n1), (2, pat.n2)):
        s = (y - n * x) / np.hypot(1, n)
        grad = np.hypot(*(np.array([-n, 1.0]) / np.hypot(1, n) @ A))  # |∇s| in projector px per camera px
        offs = pat.offsets_px(fam) / np.hypot(1, n)
        d = np.abs(s[..., None] - offs).min(axis=-1) / grad
        dist = np.minimum(dist, d)
        # each line's drawn length in the image ~ the number of pixels within half a pixel of it, one per px
        length += float((d <= 0.5).sum())
    interior = np.zeros((H, W), bool)
    interior[2:-2, 2:-2] = True
    assert target[interior].any()
    assert dist[target & interior].max() <= 0.5 + 1e-3  # never wider than one camera pixel across the line
    # and not thinner: every pixel within 0.45 px of a line's centre is in the target
    assert target[interior & (dist <= 0.45)].all()
    assert abs(int(target.sum()) - length) <= 0.05 * length
