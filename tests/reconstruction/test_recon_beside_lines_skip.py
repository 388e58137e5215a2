"""Decision 0145: `limb_lines._after_rounds` skips decision 0106's end pass (`_label_ends`, whose `_k_end_rows` walks
every trace position) when the rounds of `label_beside_lines` labelled nothing: the pass looks only at ends of pieces
the step labelled, so it has nothing to do. Checked on the small rig's pitch-16 scene (the captured call of
test_recon_limb.py): where the rounds label nothing the kernel is not run and the result is the one the pass gives;
where they label something it runs as before."""

from __future__ import annotations

import numpy as np
import pytest

import reconstruction.limb_lines as limb
from reconstruction.limb_lines import _label_ends, label_beside_lines

from tests.reconstruction.test_recon_limb import _call, _captured_call, stage16  # noqa: F401  (the fixture)


class _Counting:
    def __init__(self, real):
        self.real, self.calls = real, 0

    def __call__(self, *a, **k):
        self.calls += 1
        return self.real(*a, **k)


class _Both:
    """The calls of the end pass's kernel: `_k_end_rows`, or `_k_end_rows_after` after the compiled rounds (decision 0163)."""

    def __init__(self, a, b):
        self.a, self.b = a, b

    @property
    def calls(self):
        return self.a.calls + self.b.calls

    @calls.setter
    def calls(self, v):
        self.a.calls = v
        self.b.calls = 0


@pytest.fixture
def counted(monkeypatch):
    c = _Counting(limb._k_end_rows)
    d = _Counting(limb._k_end_rows_after)
    monkeypatch.setattr(limb, "_k_end_rows", c)
    monkeypatch.setattr(limb, "_k_end_rows_after", d)
    return _Both(c, d)


@pytest.mark.parametrize("over", [dict(margin=1e9), dict(tol_px=1e-9), dict(rounds=0)])
def test_nothing_labelled_no_end_pass(stage16, counted, over):  # noqa: F811
    """Rounds that label nothing (every piece ambiguous; no crossing within a vanishing tolerance; no round): the end
    pass is skipped, the counts are those with the pass (samples_ends 0), index and seed_jid are untouched, and the
    pass itself, run on the unchanged labels, finds no end either (what makes the skip exact)."""
    args, kw = _captured_call(stage16)
    counted.calls = 0  # (the capture ran the whole label stage)
    st, index, jid = _call(label_beside_lines, args, kw, **over)
    assert st["samples"] == 0 and st["samples_ends"] == 0
    assert counted.calls == 0
    np.testing.assert_array_equal(index, args[6])
    np.testing.assert_array_equal(jid, args[7])
    q, fam, sid, piece, ts, tangent, index0, seed_jid0 = args[:8]
    idx, sj = index0.copy(), seed_jid0.copy()
    n = _label_ends(q, fam, sid, piece, tangent, idx, sj, np.isnan(idx), model=kw["model"], depth_range_mm=kw["depth_range_mm"],
                    grid=kw["grid"], reach_px=kw["reach_px"], lateral_px=kw["lateral_px"], tol_px=kw.get("tol_px", 1.0),
                    anchor=kw.get("anchor", 3))
    assert n == 0 and counted.calls == 1
    np.testing.assert_array_equal(idx, index0)


def test_something_labelled_end_pass_runs(stage16, counted):  # noqa: F811
    """Rounds that label pieces: the end pass runs (once), as before."""
    args, kw = _captured_call(stage16)
    counted.calls = 0
    st, index, _ = _call(label_beside_lines, args, kw)
    assert st["samples"] >= 150
    assert counted.calls == 1
    assert np.sum(np.isfinite(index) & ~np.isfinite(args[6])) == st["samples"]
