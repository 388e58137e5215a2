"""Which lattice offset left the ambiguous components out, and is it the rig's geometry (decision 0147).

`labelling.label_epipolar` leaves a component out as ambiguous when its best offset and a runner-up fit the epipolar
lines nearly equally well (decisions 0004, 0122). The frame-level warning (`pipeline.left_out_warning`) only fires when
most junctions are left out, and the rig-level margin (`placement.labelling_margin`) only searches offsets
|Δ| ≤ 3. Between the two, frames lost a quarter to a half of their junctions without a warning (unseen seeds 156,
178, 193: decision 0147). This module names the competing offset per left-out component, from the component's
best-offset labels (`Labels.ambiguous_labels`): the offset d ≠ 0 whose labels best + d fit the component's epipolar
lines best (capped mean square, as the labeller scores) with at least half the component inside the working volume.
Offsets differing in sign are the same lattice vector (the runner-up on either side of the true labels); they are
counted together as ±v.

`ambiguity_report` groups the left-out junctions by that vector and measures the rig's own miss for it over the
working volume (`placement.labelling_margin` restricted to ±v). From the labeller's two conditions with the runner-up at
the rig's miss m and the best offset at the epipolar floor σ0: the ratio condition needs m ≥ min_rms_ratio·σ0 (else
no component can be decided: ill-posed for this offset), and the likelihood condition n·(m² − σ0²)/σ0² ≥ χ² needs
components of at least n_min = χ² / ((m/σ0)² − 1) junctions. Pure reporting: no label changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from reconstruction._jit import njit
from reconstruction.geometry import depth_cam, epipolar_lines, triangulate_rays
from reconstruction.rigmodel import UNLABELLED


@dataclass(frozen=True)
class AmbiguousOffset:
    """The frame's main competing lattice vector among the junctions left out as ambiguous.

    vector: (Δi, Δj), sign chosen with the first non-zero entry positive (±vector compete alike); junctions: left-out
    junctions whose component's runner-up is ±vector; components: how many components; median_size: the size of the
    component holding the median left-out junction (junction-weighted: many lone junctions do not hide a big one); rms_best, rms_runner_up: medians over those components of the best offset's and the runner-up's
    rms epipolar residual (projector px); rig_miss_px: the rig's smallest miss for ±vector over the working volume
    (`placement.labelling_margin` restricted to it; inf when it never falls inside); decide_px: the miss the
    labeller's ratio condition needs; n_min: the junctions a component needs for the likelihood condition at the
    rig's miss (inf below decide_px)."""

    vector: tuple[int, int]
    junctions: int
    components: int
    median_size: float
    rms_best: float
    rms_runner_up: float
    rig_miss_px: float
    decide_px: float
    n_min: float

    @property
    def geometric(self) -> bool:
        """The rig's geometry explains the ambiguity: no component can be decided (miss under decide_px) or the
        median left-out component is smaller than the junctions the likelihood condition needs."""
        return self.rig_miss_px < self.decide_px or self.median_size < self.n_min


@njit
def _offset_scores(best, lines, comp, n_c, xy_junction, index_min, index_max, fx, offs, cap2):
    """Per component (comp (n,) in 0..n_c−1) and offset offs (K, 2): the sum over its junctions of the capped squared
    epipolar distance (projector px²) of label best + offset (cap2 outside the pattern), and how many are inside."""
    n = best.shape[0]
    K = offs.shape[0]
    score = np.zeros((n_c, K))
    n_in = np.zeros((n_c, K))
    for a in range(n):
        c = comp[a]
        for k in range(K):
            i = best[a, 0] + offs[k, 0]
            j = best[a, 1] + offs[k, 1]
            if i < index_min or i > index_max or j < index_min or j > index_max:
                score[c, k] += cap2
                continue
            x = xy_junction[i - index_min, j - index_min, 0]
            y = xy_junction[i - index_min, j - index_min, 1]
            r = (lines[a, 0] * x + lines[a, 1] * y + lines[a, 2]) * fx
            score[c, k] += min(r * r, cap2)
            n_in[c, k] += 1.0
    return score, n_in


def competing_offsets(model, xy_cam: np.ndarray, best: np.ndarray, component: np.ndarray, *, depth_range_mm: tuple[float, float],
                      cap_px: float = 1.0, max_offset: int = 12, min_inside: float = 0.5) -> dict:
    """Per component with best-offset labels (best (M, 2), UNLABELLED elsewhere): its runner-up offset among
    |Δi|, |Δj| ≤ max_offset. xy_cam (M, 2): the junctions' normalised camera points; component (M,): ids.

    Returns {component id: (members (m,), offset (2,) or None, rms_best, rms_runner_up)} (projector px; the runner-up
    None when no offset keeps min_inside of the component inside the pattern and the working volume)."""
    sel = np.flatnonzero(best[:, 0] != UNLABELLED)
    out: dict = {}
    if len(sel) == 0:
        return out
    procam = model.procam
    lines = epipolar_lines(procam, xy_cam[sel])
    comp_ids, inv = np.unique(component[sel], return_inverse=True)
    n_c = len(comp_ids)
    size = np.bincount(inv, minlength=n_c).astype(np.float64)
    offs = np.array([(a, b) for a in range(-max_offset, max_offset + 1) for b in range(-max_offset, max_offset + 1)], np.int64)
    cap2 = float(cap_px) ** 2
    order = np.argsort(inv, kind="stable")
    starts = np.searchsorted(inv[order], np.arange(n_c))
    b_sel = np.ascontiguousarray(best[sel], np.int64)
    score, n_in = _offset_scores(b_sel, np.ascontiguousarray(lines, np.float64), inv.astype(np.int64), int(n_c), model.xy_junction,
                                 int(model.index_min), int(model.index_max), float(model.fx_proj), offs, cap2)
    score /= size[:, None]  # (n_c, K) capped mean squares
    k0 = int(np.flatnonzero((offs == 0).all(1))[0])
    score_k = np.where(n_in >= min_inside * size[:, None], score, np.inf)
    score_k[:, k0] = np.inf
    n_try = 4  # the best few by score: the first with min_inside of the component in the working volume
    top = np.argsort(score_k, axis=1, kind="stable")[:, :n_try]  # (n_c, n_try)
    # every left-out junction under each of its component's candidates, triangulated in one call
    kk = top[inv]  # (n, n_try)
    lb = np.repeat(b_sel, n_try, axis=0) + offs[kk.ravel()]
    inside = (lb >= model.index_min).all(1) & (lb <= model.index_max).all(1)
    lb = np.clip(lb, model.index_min, model.index_max)
    p, _ = triangulate_rays(procam, np.repeat(xy_cam[sel], n_try, axis=0), model.junction_xy(lb[:, 0], lb[:, 1]))
    z = depth_cam(procam, p)
    lo, hi = depth_range_mm
    good = np.isfinite(z) & (z >= lo) & (z <= hi) & inside
    frac = np.add.reduceat(good.reshape(-1, n_try)[order].astype(np.float64), starts, axis=0) / size[:, None]  # (n_c, n_try)
    passing = (frac >= min_inside) & np.isfinite(np.take_along_axis(score_k, top, axis=1))
    has = passing.any(1)
    first = np.argmax(passing, axis=1)
    chosen = top[np.arange(n_c), first]
    for c in range(n_c):
        members = sel[order[starts[c]:starts[c] + int(size[c])]]
        k = int(chosen[c])
        out[int(comp_ids[c])] = (members, offs[k].copy() if has[c] else None, math.sqrt(score[c, k0]),
                                 math.sqrt(score[c, k]) if has[c] else math.nan)
    return out


def canonical(v) -> tuple[int, int]:
    """±v as one vector: the first non-zero entry positive."""
    a, b = int(v[0]), int(v[1])
    return (a, b) if (a > 0 or (a == 0 and b > 0)) else (-a, -b)


def ambiguity_report(model, pattern, xy_cam: np.ndarray, best: np.ndarray, component: np.ndarray, *, depth_range_mm: tuple[float, float],
                     noise_floor_px: float, min_rms_ratio: float, chi2: float, cap_px: float = 1.0,
                     max_offset: int = 12) -> tuple[dict, AmbiguousOffset | None]:
    """Left-out junctions per competing lattice vector ({"(a, b)": junctions}, "none" where no runner-up was found)
    and the main vector's `AmbiguousOffset` (None without one)."""
    from reconstruction.placement import labelling_margin

    per = competing_offsets(model, xy_cam, best, component, depth_range_mm=depth_range_mm, cap_px=cap_px, max_offset=max_offset)
    groups: dict = {}
    for members, off, s1, s2 in per.values():
        key = "none" if off is None else canonical(off)
        g = groups.setdefault(key, [0, [], [], []])
        g[0] += len(members)
        g[1].append(len(members))
        g[2].append(s1)
        g[3].append(s2)
    counts = {(k if isinstance(k, str) else f"({k[0]}, {k[1]})"): int(g[0]) for k, g in groups.items()}
    vecs = [k for k in groups if not isinstance(k, str)]
    if not vecs:
        return counts, None
    v = max(vecs, key=lambda k: groups[k][0])
    g = groups[v]
    if pattern is None:  # the indices are all labelling_margin needs with the model's junction points
        pattern = SimpleNamespace(indices=np.arange(model.index_min, model.index_max + 1))
    m = labelling_margin(model.procam, pattern, depth_range_mm=depth_range_mm, offsets=[v, (-v[0], -v[1])], junction_xy=model.junction_xy)
    decide = float(min_rms_ratio) * float(noise_floor_px)
    q = (m.margin_px / float(noise_floor_px)) ** 2 - 1.0
    n_min = math.inf if (m.margin_px < decide or q <= 0) else float(chi2) / q
    sizes = np.sort(np.repeat(g[1], g[1]))  # one entry per junction: its component's size
    return counts, AmbiguousOffset(v, int(g[0]), len(g[1]), float(np.median(sizes)), float(np.median(g[2])), float(np.median(g[3])),
                                   float(m.margin_px), decide, n_min)


def ambiguity_warning(n_junctions: int, n_ambiguous: int, main: AmbiguousOffset | None, n_open: int | None = None) -> str:
    """The frame's sentence for a share of junctions left out as ambiguous (see `pipeline.ambiguous_share_warning`);
    n_open: how many of them have no point nearby in the result."""
    head = f"{n_ambiguous} of {n_junctions} junctions ({100.0 * n_ambiguous / max(n_junctions, 1):.0f} %) were left out as ambiguous"
    if n_open is not None:
        head += f" ({n_open} with no point nearby)"
    if main is None:
        return head + " (see stats: junctions_left_out)"
    a, b = main.vector
    head += (f"; {main.junctions} of them in {main.components} components (half of the junctions in components of {main.median_size:.0f} or fewer) whose labels "
             f"moved by the lattice offset ±({a}, {b}) fit the epipolar lines almost as well (runner-up {main.rms_runner_up:.2f} px "
             f"against {main.rms_best:.2f} px, medians)")
    if not math.isfinite(main.rig_miss_px):
        return head + " (see stats: ambiguous_offsets)"
    if main.rig_miss_px < main.decide_px:
        return (head + f"; the rig misses ±({a}, {b}) by only {main.rig_miss_px:.3f} projector px over the working volume, under the "
                f"{main.decide_px:.2f} px the labeller needs: this lattice vector lies along the epipolar lines, so no component can be "
                "told apart; move the camera in another direction from the projector, change the pattern angles, tighten the "
                "[reconstruction] depth range, or use spacing = \"debruijn\"")
    if main.median_size < main.n_min:
        return (head + f"; the rig misses ±({a}, {b}) by {main.rig_miss_px:.3f} projector px over the working volume, so a component "
                f"needs about {math.ceil(main.n_min)} junctions to be told apart: the grid is broken into pieces too small for this "
                "rig; a larger baseline or another camera direction, a tighter depth range, or spacing = \"debruijn\" helps")
    return head + (f"; the rig misses ±({a}, {b}) by {main.rig_miss_px:.3f} projector px, enough for components this size: not the "
                   "rig's geometry (mixed surfaces or junction noise; see stats: junctions_left_out)")
