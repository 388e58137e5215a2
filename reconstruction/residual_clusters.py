"""A labelled component's junctions whose epipolar residuals are high *together* (decision 0108).

The graph joins junctions that a visible segment links. At a depth edge a line of the background can continue a
line of the foreground in the image, and the segment joins the two surfaces. Usually the labels then contradict
each other around a cycle (`clean_edges`), or the attached part fits the component's offset badly (outliers).
Neither happens when the two surfaces' true labels differ by a lattice vector (Δi, Δj) that runs almost along the
epipolar lines there. Those vectors are long (on unseen pitch-14 rigs: (−5, 11), (−6, 6)), and the depth range
admits them. The attached part then fits the component's offset *almost* as well: each of its junctions stays
under the outlier limit (0.3 px). As a group, though, they sit 5–15 times the component's residual scale σ̂ off
their epipolar lines, while the rest of the component sits at about σ̂. One such part gave 1 028 points with
27 % relative error (3 % of the frame) and no warning.

`elevated_pieces` finds them:
- Each junction's local level is the median residual over itself and its graph neighbours (kept edges, same
  component). A median, so that one outlier does not raise its neighbours.
- Junctions whose local level exceeds max(`factor`·σ̂, `floor_px`) are *elevated*. The floor keeps systematic
  biases of a few hundredths of a projector pixel (on the sweep's 640×512 rig σ̂ is 0.01 px) from splitting a
  right component. Elevated junctions that form a connected group of at least `min_cluster` are taken out,
  like outliers.
- When that happens, the rest of the component is split into its connected pieces without them. The largest
  piece keeps the offset, and so does every piece with more junctions than the groups taken out. The smaller
  pieces are labelled again on their own, like outliers: the wrong part's junctions with low residuals, its
  fringe, are cut off this way too. Alone, such a piece takes its own offset or is left out as ambiguous.
- A component without an elevated group is left as it is.
"""

from __future__ import annotations

import math

import numpy as np

from reconstruction._jit import njit


@njit
def kept_adjacency(n, a, b, keep):
    """CSR adjacency (start (n + 1,), nbr) of the kept edges (a, b (E,) junction ids, keep (E,) bool)."""
    start = np.zeros(n + 1, np.intp)
    for e in range(a.shape[0]):
        if keep[e]:
            start[a[e] + 1] += 1
            start[b[e] + 1] += 1
    for k in range(n):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    nbr = np.empty(start[n], np.intp)
    for e in range(a.shape[0]):
        if keep[e]:
            nbr[fill[a[e]]] = b[e]
            fill[a[e]] += 1
            nbr[fill[b[e]]] = a[e]
            fill[b[e]] += 1
    return start, nbr


@njit
def _median(x, n):
    """Median of x[:n] (n ≥ 1), sorting x[:n] in place."""
    y = np.sort(x[:n])
    h = n // 2
    return y[h] if n % 2 == 1 else 0.5 * (y[h - 1] + y[h])


@njit
def _median_in_place(x, n):
    """`_median(x, n)` by an insertion sort of x[:n] in place (decision 0127: the rings of `elevated_pieces` hold a
    junction and its few neighbours; `_median`'s np.sort allocated a copy per junction). The sorted values are the
    same whatever the sort, so the median is the same number."""
    for i in range(1, n):
        v = x[i]
        j = i - 1
        while j >= 0 and x[j] > v:
            x[j + 1] = x[j]
            j -= 1
        x[j + 1] = v
    h = n // 2
    return x[h] if n % 2 == 1 else 0.5 * (x[h - 1] + x[h])


@njit
def _flood(k, allowed, mark, members, start, nbr, pos, stack, found):
    """The connected set of component positions reachable from k over kept edges through `allowed` positions not
    yet marked: marks them with k (mark (m,), −1 = unmarked), lists them in found[:n] and returns n. stack: work
    space (m,)."""
    mark[k] = k
    stack[0] = k
    ns = 1
    n = 0
    while ns > 0:
        ns -= 1
        c = stack[ns]
        found[n] = c
        n += 1
        j = members[c]
        for t in range(start[j], start[j + 1]):
            p = pos[nbr[t]]
            if p >= 0 and allowed[p] and mark[p] < 0:
                mark[p] = k
                stack[ns] = p
                ns += 1
    return n


@njit
def elevated_pieces(members, residual, bad, start, nbr, pos, factor, floor_px, min_cluster):
    """For one accepted component (members (m,) junction ids, residual (M,) its residuals in projector px, NaN
    where none; bad (m,) the outliers already found), the junctions to take out as well (module doc).

    A junction is elevated when its local median exceeds max(factor·σ̂, floor_px): systematic biases of a few
    hundredths of a projector pixel (junctions at a depth edge, a slanted surface) stay below floor_px.
    start, nbr: `kept_adjacency`; pos (M,) intp all −1 (work space, restored on return). Returns out (m,) bool
    (True: take out; includes bad) and the number of junctions newly taken out (0: leave the component as it is)."""
    m = members.shape[0]
    out = bad.copy()
    if m == 0:
        return out, 0
    for k in range(m):
        pos[members[k]] = k
    # the component's residual scale σ̂ over its inliers (as labelling._outlier_limit)
    buf = np.empty(m)
    nf = 0
    for k in range(m):
        x = residual[members[k]]
        if not bad[k] and math.isfinite(x):
            buf[nf] = abs(x)
            nf += 1
    added = 0
    if nf >= 2 * min_cluster:
        sigma = 1.4826 * _median(buf, nf)
        # local level: the median residual over the junction and its neighbours in the component (inliers)
        deg_max = 0
        for k in range(m):
            deg_max = max(deg_max, start[members[k] + 1] - start[members[k]])
        ring = np.empty(deg_max + 1)
        elev = np.zeros(m, np.bool_)
        for k in range(m):
            if bad[k]:
                continue
            j = members[k]
            nr = 0
            x = residual[j]
            if math.isfinite(x):
                ring[nr] = abs(x)
                nr += 1
            for t in range(start[j], start[j + 1]):
                p = pos[nbr[t]]
                if p >= 0 and not bad[p]:
                    y = residual[nbr[t]]
                    if math.isfinite(y):
                        ring[nr] = abs(y)
                        nr += 1
            if nr >= 2 and _median_in_place(ring, nr) > max(factor * sigma, floor_px):
                elev[k] = True
        # connected groups of elevated junctions; those of at least min_cluster are taken out
        group = np.full(m, -1, np.intp)
        stack = np.empty(m, np.intp)
        members_g = np.empty(m, np.intp)  # the current group's positions
        taken = np.zeros(m, np.bool_)
        for k in range(m):
            if elev[k] and group[k] < 0:
                ng = _flood(k, elev, group, members, start, nbr, pos, stack, members_g)
                if ng >= min_cluster:
                    for h in range(ng):
                        taken[members_g[h]] = True
        n_taken = 0
        for k in range(m):
            if taken[k]:
                out[k] = True
                n_taken += 1
        if n_taken > 0:
            # the rest in connected pieces: the largest keeps the offset, and so does every piece larger than the
            # groups taken out (a part joined across a depth edge is the group and its fringe)
            rest = ~out
            piece = np.full(m, -1, np.intp)
            size = np.zeros(m, np.intp)
            best = -1
            best_n = 0
            for k in range(m):
                if rest[k] and piece[k] < 0:
                    cnt = _flood(k, rest, piece, members, start, nbr, pos, stack, members_g)
                    size[k] = cnt
                    if cnt > best_n:
                        best_n = cnt
                        best = k
            for k in range(m):
                if not out[k] and piece[k] != best and size[piece[k]] <= n_taken:
                    out[k] = True
            for k in range(m):
                if out[k] and not bad[k]:
                    added += 1
    for k in range(m):
        pos[members[k]] = -1
    return out, added
