"""De Bruijn-spaced line offsets for the grid pattern (after Ulusoy, Calakli & Taubin, 2009).

A uniform grid is periodic: shifting the labels by one line moves every junction onto another junction, which is
where the single-shot method's sensitivity to calibration and noise comes from. Drawing the spacing between
consecutive lines from a small set of values in De Bruijn order breaks that symmetry: every run of `n`
consecutive spacings occurs once in the pattern, so a wrong label shift makes the observed spacings disagree with
the projected ones. The lines stay straight and the pattern stays one shot; `GridPattern(spacing="debruijn")`
uses these offsets in place of `i · pitch_px` (CONVENTIONS.md, "The projected grid").
"""

from __future__ import annotations

import numpy as np


def debruijn_sequence(k: int, n: int) -> np.ndarray:
    """The lexicographically least De Bruijn sequence B(k, n): (k**n,) int symbols in 0 … k−1.

    Read cyclically, every word of length n over k symbols occurs exactly once as n consecutive symbols.
    Built by concatenating the Lyndon words whose length divides n, in lexicographic order
    (Fredricksen–Kessler–Maiorana).
    """
    if k < 2 or n < 1:
        raise ValueError(f"a De Bruijn sequence needs k >= 2 symbols and order n >= 1, got k={k}, n={n}")
    if k**n > 10_000_000:
        raise ValueError(f"B({k}, {n}) would have {k**n} symbols; use a smaller k or n")
    a = [0] * (n + 1)
    out: list[int] = []

    def db(t: int, p: int) -> None:
        # Iterative form would be faster; recursion depth is only n.
        if t > n:
            if n % p == 0:
                out.extend(a[1 : p + 1])
            return
        a[t] = a[t - p]
        db(t + 1, p)
        for j in range(a[t - p] + 1, k):
            a[t] = j
            db(t + 1, t)

    db(1, 1)
    return np.asarray(out, dtype=np.int64)


def spacing_values_px(pitch_px: float, *, k: int = 3, spread: float = 0.25) -> np.ndarray:
    """The k spacings (k,) in px: pitch_px · (1 + spread · (s − (k−1)/2) / ((k−1)/2)), s = 0 … k−1.

    They are symmetric around pitch_px, from pitch_px·(1 − spread) to pitch_px·(1 + spread).
    """
    if not 0 < spread < 1:
        raise ValueError(f"spread must be in (0, 1) so that every spacing is positive, got {spread}")
    half = (k - 1) / 2
    return pitch_px * (1.0 + spread * (np.arange(k) - half) / half)


def debruijn_order(lines: int, k: int) -> int:
    """The smallest order n with k**n >= lines − 1: enough windows for every spacing of a `lines`-line family."""
    n = 1
    while k**n < lines - 1:
        n += 1
    return n


def debruijn_symbols(lines: int, *, k: int = 3, n: int | None = None) -> np.ndarray:
    """The (lines − 1,) spacing symbols: a cyclic run of B(k, n), every window of n consecutive symbols unique.

    Of the k**n cyclic runs, the one taken makes the family no wider than the uniform grid on either side of
    index 0 (or as little wider as possible when no run allows it) and, among those, closest to the uniform
    grid's width, so that the spacings are used about evenly; ties go to the earliest start.
    """
    if lines < 2:
        raise ValueError(f"a line family needs at least 2 lines, got {lines}")
    n = debruijn_order(lines, k) if n is None else n
    seq = debruijn_sequence(k, n)
    m = lines - 1
    if m > len(seq):
        raise ValueError(
            f"B({k}, {n}) has {len(seq)} windows, too few for {lines} lines with unique windows; raise k or n"
        )
    h = (lines - 1) // 2  # array position of index 0 (GridPattern.indices)
    centred = seq - (k - 1) / 2  # signed deviation of each spacing from the pitch, in steps
    # Excess width (in steps) of the left part (first h spacings) and the right part, for every cyclic start.
    ext = np.concatenate([centred, centred[:m]])
    csum = np.concatenate([[0.0], np.cumsum(ext)])
    starts = np.arange(len(seq))
    left = csum[starts + h] - csum[starts]
    right = csum[starts + m] - csum[starts + h]
    # Never wider than the uniform grid on either side where some run allows it, else as little wider as
    # possible; among those, the run closest to the uniform grid's width (spacings used evenly).
    overflow = np.maximum(left, right)
    shortfall = np.maximum(-left, -right)
    allowed = overflow <= max(overflow.min(), 0.0) + 1e-9
    score = np.where(allowed, shortfall, np.inf)
    best = int(np.flatnonzero(score <= score.min() + 1e-9)[0])
    return np.concatenate([seq, seq])[best : best + m]


def debruijn_offsets_px(
    lines: int, pitch_px: float, *, k: int = 3, n: int | None = None, spread: float = 0.25
) -> np.ndarray:
    """Offsets (lines,) in px of one line family, in index order, strictly increasing, 0 at index 0.

    Consecutive offsets differ by one of `spacing_values_px(pitch_px, k=k, spread=spread)`, in the order of
    `debruijn_symbols(lines, k=k, n=n)`: every run of n consecutive spacings is unique within the family.
    Index 0 sits at array position (lines − 1) // 2, as in `GridPattern.indices`. With the defaults (k = 3,
    spread = 0.25) the spacings are 0.75, 1 and 1.25 × pitch_px and n is the smallest order giving enough windows.
    """
    symbols = debruijn_symbols(lines, k=k, n=n)
    spacing = spacing_values_px(pitch_px, k=k, spread=spread)[symbols]
    offsets = np.concatenate([[0.0], np.cumsum(spacing)])
    return offsets - offsets[(lines - 1) // 2]
