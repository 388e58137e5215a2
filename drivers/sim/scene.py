"""The simulated workspace: analytic primitives and vectorised ray casting.

Everything is in the world (= projector) frame, millimetres (CONVENTIONS.md). A ray is an origin `o`
((N, 3) or (1, 3)) and a direction `d` ((N, 3), any length): the point at parameter `t` is `o + t·d`.
Every primitive answers `intersect(o, d, t_min=…) -> (t (N,), n (N, 3))`: the smallest `t > t_min` at
which the ray meets its surface (`inf` where it does not) and the unit outward surface normal there (NaN
where there is no hit). All solids are convex and all flat objects are flat, so no object can cast a
shadow on itself at a point whose normal faces the light: the shadow test skips the object the point
lies on (docs/decisions/0011-sim-shadow-test.md).

Each primitive has an `albedo` (Lambertian reflectance, 0…1); a TexturedPlane multiplies it by its
texture.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence, Union

import cv2
import numpy as np

_TINY = 1e-300


def _vec3(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be 3 finite numbers, got {v!r}")
    a.setflags(write=False)
    return a


def _unit(v, name: str) -> np.ndarray:
    a = np.array(_vec3(v, name))
    n = np.linalg.norm(a)
    if n < 1e-12:
        raise ValueError(f"{name} must be a non-zero direction, got {v!r}")
    a /= n
    a.setflags(write=False)
    return a


def _rotation(R, name: str) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64).reshape(3, 3).copy()
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"{name} must be a rotation matrix (orthonormal, determinant +1)")
    R.setflags(write=False)
    return R


def _albedo(a: float) -> float:
    a = float(a)
    if not 0.0 <= a <= 1.0:
        raise ValueError(f"albedo must be in [0, 1], got {a}")
    return a


def _basis(axis: np.ndarray) -> np.ndarray:
    """A rotation whose third column is `axis` (unit); the other two complete a right-handed frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, axis)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    return np.column_stack([e1, e2, axis])


def _nan_normals(n: int) -> np.ndarray:
    return np.full((n, 3), np.nan)


# --------------------------------------------------------------------------------------------------------
# primitives
# --------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Plane:
    """An infinite plane through `point_mm` with normal `normal` (either side reflects)."""

    point_mm: np.ndarray
    normal: np.ndarray
    albedo: float = 0.8

    def __post_init__(self) -> None:
        object.__setattr__(self, "point_mm", _vec3(self.point_mm, "Plane.point_mm"))
        object.__setattr__(self, "normal", _unit(self.normal, "Plane.normal"))
        object.__setattr__(self, "albedo", _albedo(self.albedo))

    def bound(self) -> tuple[np.ndarray, float] | None:
        return None

    def intersect(self, o: np.ndarray, d: np.ndarray, *, t_min: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        denom = d @ self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.point_mm - o) @ self.normal) / denom
        t = np.where((np.abs(denom) > 1e-15) & (t > t_min), t, np.inf)
        n = np.broadcast_to(self.normal, (len(t), 3)).copy()
        n[~np.isfinite(t)] = np.nan
        return t, n

    def albedo_at(self, p: np.ndarray) -> np.ndarray:
        return np.full(len(p), self.albedo)


@dataclass(frozen=True, eq=False)
class Box:
    """A rectangular box: centre `centre_mm`, edge lengths `size_mm` along its own axes, which are the
    columns of `R_proj_box` (world frame)."""

    centre_mm: np.ndarray
    size_mm: np.ndarray
    R_proj_box: np.ndarray = field(default_factory=lambda: np.eye(3))
    albedo: float = 0.8

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_mm", _vec3(self.centre_mm, "Box.centre_mm"))
        size = _vec3(self.size_mm, "Box.size_mm")
        if np.any(size <= 0):
            raise ValueError(f"Box.size_mm must be positive, got {size.tolist()}")
        object.__setattr__(self, "size_mm", size)
        object.__setattr__(self, "R_proj_box", _rotation(self.R_proj_box, "Box.R_proj_box"))
        object.__setattr__(self, "albedo", _albedo(self.albedo))

    def bound(self) -> tuple[np.ndarray, float] | None:
        return self.centre_mm, float(np.linalg.norm(self.size_mm) / 2)

    def intersect(self, o: np.ndarray, d: np.ndarray, *, t_min: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        # Slabs in the box's own frame.
        o_box = (o - self.centre_mm) @ self.R_proj_box
        d_box = d @ self.R_proj_box
        d_box = np.where(np.abs(d_box) < _TINY, _TINY, d_box)
        half = self.size_mm / 2
        inv = 1.0 / d_box
        t1 = (-half - o_box) * inv
        t2 = (half - o_box) * inv
        t_lo = np.minimum(t1, t2)
        t_hi = np.maximum(t1, t2)
        t_near = t_lo.max(axis=1)
        t_far = t_hi.min(axis=1)
        hit = (t_near <= t_far) & (t_far > t_min)
        entering = t_near > t_min
        t = np.where(hit, np.where(entering, t_near, t_far), np.inf)
        axis = np.where(entering, t_lo.argmax(axis=1), t_hi.argmin(axis=1))
        rows = np.arange(len(t))
        sign = np.sign(d_box[rows, axis])
        n_box = np.zeros((len(t), 3))
        n_box[rows, axis] = np.where(entering, -sign, sign)
        n = n_box @ self.R_proj_box.T
        n[~hit] = np.nan
        return t, n

    def albedo_at(self, p: np.ndarray) -> np.ndarray:
        return np.full(len(p), self.albedo)


def _frustum_intersect(
    frame: np.ndarray, base: np.ndarray, r0: float, r1: float, h: float, o: np.ndarray, d: np.ndarray, t_min: float
) -> tuple[np.ndarray, np.ndarray]:
    """Ray vs a capped frustum (base radius r0 at z = 0, top radius r1 at z = h, z along frame[:, 2])."""
    ol = (o - base) @ frame
    dl = d @ frame
    ol = np.broadcast_to(ol, dl.shape)
    s = (r1 - r0) / h
    ox, oy, oz = ol[:, 0], ol[:, 1], ol[:, 2]
    dx, dy, dz = dl[:, 0], dl[:, 1], dl[:, 2]
    # Side: x² + y² = ρ(z)², ρ(z) = r0 + s·z, 0 <= z <= h; with z = oz + t·dz a quadratic in t.
    A = r0 + s * oz
    B = s * dz
    a = dx * dx + dy * dy - B * B
    b = 2 * (ox * dx + oy * dy - A * B)
    c = ox * ox + oy * oy - A * A
    best = np.full(len(dl), np.inf)
    kind = np.zeros(len(dl), np.int8)  # 1 side, 2 bottom cap, 3 top cap
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4 * a * c
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        q = -0.5 * (b + np.copysign(sq, b))  # the numerically stable pair of roots q/a, c/q
        quad = np.abs(a) > 1e-12 * (dx * dx + dy * dy + dz * dz)
        roots = (np.where(quad, q / a, -c / b), np.where(quad, c / q, np.nan))
        for t in roots:
            z = oz + t * dz
            ok = np.isfinite(t) & (t > t_min) & (z >= 0) & (z <= h) & (t < best)
            best = np.where(ok, t, best)
            kind = np.where(ok, 1, kind)
        for zc, r, k in ((0.0, r0, 2), (h, r1, 3)):
            if r <= 0:
                continue
            t = (zc - oz) / dz
            x = ox + t * dx
            y = oy + t * dy
            ok = np.isfinite(t) & (t > t_min) & (x * x + y * y <= r * r) & (t < best)
            best = np.where(ok, t, best)
            kind = np.where(ok, k, kind)
    hit = kind > 0
    p = ol + np.where(hit, best, 0.0)[:, None] * dl
    rho = r0 + s * p[:, 2]
    nl = np.column_stack([p[:, 0], p[:, 1], -rho * s])  # gradient of x² + y² − ρ(z)²
    nl[kind == 2] = (0.0, 0.0, -1.0)
    nl[kind == 3] = (0.0, 0.0, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        nl /= np.linalg.norm(nl, axis=1, keepdims=True)
    n = nl @ frame.T
    n[~hit] = np.nan
    return best, n


@dataclass(frozen=True, eq=False)
class Cone:
    """A capped cone or frustum standing on its base disc.

    base_mm: centre of the base disc; axis: direction from the base towards the top; radius_mm: base
    radius; height_mm: along the axis; top_radius_mm: 0 for a pointed cone (the apex at the top), > 0 for
    a frustum (capped at the top too).
    """

    base_mm: np.ndarray
    axis: np.ndarray
    radius_mm: float
    height_mm: float
    top_radius_mm: float = 0.0
    albedo: float = 0.8

    def __post_init__(self) -> None:
        object.__setattr__(self, "base_mm", _vec3(self.base_mm, "Cone.base_mm"))
        object.__setattr__(self, "axis", _unit(self.axis, "Cone.axis"))
        r0, r1, h = float(self.radius_mm), float(self.top_radius_mm), float(self.height_mm)
        if r0 < 0 or r1 < 0 or h <= 0 or max(r0, r1) <= 0:
            raise ValueError(f"Cone: radii must be >= 0 (not both 0) and height > 0, got radius_mm={r0}, top_radius_mm={r1}, height_mm={h}")
        object.__setattr__(self, "albedo", _albedo(self.albedo))
        object.__setattr__(self, "_frame", _basis(self.axis))

    def bound(self) -> tuple[np.ndarray, float] | None:
        centre = self.base_mm + self.axis * self.height_mm / 2
        return centre, float(np.hypot(self.height_mm / 2, max(self.radius_mm, self.top_radius_mm)))

    def intersect(self, o: np.ndarray, d: np.ndarray, *, t_min: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        return _frustum_intersect(
            self._frame, self.base_mm, float(self.radius_mm), float(self.top_radius_mm), float(self.height_mm), o, d, t_min
        )

    def albedo_at(self, p: np.ndarray) -> np.ndarray:
        return np.full(len(p), self.albedo)


@dataclass(frozen=True, eq=False)
class Cylinder:
    """A capped circular cylinder: base disc centre `base_mm`, `axis` towards the top, radius, height."""

    base_mm: np.ndarray
    axis: np.ndarray
    radius_mm: float
    height_mm: float
    albedo: float = 0.8

    def __post_init__(self) -> None:
        object.__setattr__(self, "base_mm", _vec3(self.base_mm, "Cylinder.base_mm"))
        object.__setattr__(self, "axis", _unit(self.axis, "Cylinder.axis"))
        if not (self.radius_mm > 0 and self.height_mm > 0):
            raise ValueError(f"Cylinder: radius_mm and height_mm must be positive, got {self.radius_mm}, {self.height_mm}")
        object.__setattr__(self, "albedo", _albedo(self.albedo))
        object.__setattr__(self, "_frame", _basis(self.axis))

    def bound(self) -> tuple[np.ndarray, float] | None:
        centre = self.base_mm + self.axis * self.height_mm / 2
        return centre, float(np.hypot(self.height_mm / 2, self.radius_mm))

    def intersect(self, o: np.ndarray, d: np.ndarray, *, t_min: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        r = float(self.radius_mm)
        return _frustum_intersect(self._frame, self.base_mm, r, r, float(self.height_mm), o, d, t_min)

    def albedo_at(self, p: np.ndarray) -> np.ndarray:
        return np.full(len(p), self.albedo)


@dataclass(frozen=True, eq=False)
class Sphere:
    """A sphere of radius `radius_mm` centred at `centre_mm`."""

    centre_mm: np.ndarray
    radius_mm: float
    albedo: float = 0.8

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre_mm", _vec3(self.centre_mm, "Sphere.centre_mm"))
        if self.radius_mm <= 0:
            raise ValueError(f"Sphere.radius_mm must be positive, got {self.radius_mm}")
        object.__setattr__(self, "albedo", _albedo(self.albedo))

    def bound(self) -> tuple[np.ndarray, float] | None:
        return self.centre_mm, float(self.radius_mm)

    def intersect(self, o: np.ndarray, d: np.ndarray, *, t_min: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        oc = np.broadcast_to(o - self.centre_mm, d.shape)
        a = np.einsum("ij,ij->i", d, d)
        b = np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - self.radius_mm**2
        disc = b * b - a * c
        with np.errstate(invalid="ignore"):
            sq = np.sqrt(disc)
        t_near = (-b - sq) / a
        t_far = (-b + sq) / a
        t = np.where(t_near > t_min, t_near, np.where(t_far > t_min, t_far, np.inf))
        t = np.where(disc >= 0, t, np.inf)
        hit = np.isfinite(t)
        n = (oc + np.where(hit, t, 0.0)[:, None] * d) / self.radius_mm
        n[~hit] = np.nan
        return t, n

    def albedo_at(self, p: np.ndarray) -> np.ndarray:
        return np.full(len(p), self.albedo)


@dataclass(frozen=True, eq=False)
class TexturedPlane:
    """A finite flat board carrying a printed texture (a chessboard, a ChArUco board, a photo).

    Pose: p_proj = R_proj_board · p_board + t_proj_board (mm); the board frame has x along the texture's
    columns, y along its rows, z into the board (CONVENTIONS.md). texture: (Ht, Wt) grey image (uint8
    0…255, or float 0…1) multiplying `albedo`; mm_per_texel: the printed size of one texel;
    texture_origin_mm: board-frame (x, y) of the texture's top-left corner, e.g. (−40, −40) if the board
    origin (the first inner chessboard corner) lies 40 mm in from the corner of the print. The board is
    exactly as large as the texture; both faces show it. Texture lookup is bilinear with texel (c, r)
    centred at x = x0 + (c + ½)·mm_per_texel: keep a texel no larger than a camera subsample footprint
    (there is no mip-mapping).
    """

    R_proj_board: np.ndarray
    t_proj_board: np.ndarray
    texture: np.ndarray
    mm_per_texel: float
    texture_origin_mm: tuple[float, float] = (0.0, 0.0)
    albedo: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "R_proj_board", _rotation(self.R_proj_board, "TexturedPlane.R_proj_board"))
        object.__setattr__(self, "t_proj_board", _vec3(self.t_proj_board, "TexturedPlane.t_proj_board"))
        tex = np.asarray(self.texture)
        if tex.ndim != 2 or min(tex.shape) < 1:
            raise ValueError(f"TexturedPlane.texture must be a (H, W) grey image, got shape {tex.shape}")
        scale = 1 / 255 if tex.dtype == np.uint8 else (1 / 65535 if tex.dtype == np.uint16 else 1.0)
        tex = np.clip(tex.astype(np.float32) * np.float32(scale), 0, 1)
        tex.setflags(write=False)
        object.__setattr__(self, "texture", tex)
        if not self.mm_per_texel > 0:
            raise ValueError(f"TexturedPlane.mm_per_texel must be positive, got {self.mm_per_texel}")
        x0, y0 = (float(v) for v in self.texture_origin_mm)
        object.__setattr__(self, "texture_origin_mm", (x0, y0))
        object.__setattr__(self, "albedo", _albedo(self.albedo))

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) of the board in mm."""
        h, w = self.texture.shape
        return w * self.mm_per_texel, h * self.mm_per_texel

    def bound(self) -> tuple[np.ndarray, float] | None:
        w, h = self.size_mm
        x0, y0 = self.texture_origin_mm
        centre_board = np.array([x0 + w / 2, y0 + h / 2, 0.0])
        return self.R_proj_board @ centre_board + self.t_proj_board, float(np.hypot(w, h) / 2)

    def intersect(self, o: np.ndarray, d: np.ndarray, *, t_min: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        ob = (o - self.t_proj_board) @ self.R_proj_board
        db = d @ self.R_proj_board
        ob = np.broadcast_to(ob, db.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -ob[:, 2] / db[:, 2]
        x = ob[:, 0] + t * db[:, 0]
        y = ob[:, 1] + t * db[:, 1]
        w, h = self.size_mm
        x0, y0 = self.texture_origin_mm
        ok = np.isfinite(t) & (t > t_min) & (x >= x0) & (x <= x0 + w) & (y >= y0) & (y <= y0 + h)
        t = np.where(ok, t, np.inf)
        n = np.broadcast_to(self.R_proj_board[:, 2], (len(t), 3)).copy()
        n[~ok] = np.nan
        return t, n

    def albedo_at(self, p: np.ndarray) -> np.ndarray:
        pb = (np.asarray(p, np.float64) - self.t_proj_board) @ self.R_proj_board
        x0, y0 = self.texture_origin_mm
        c = ((pb[:, 0] - x0) / self.mm_per_texel - 0.5).astype(np.float32)
        r = ((pb[:, 1] - y0) / self.mm_per_texel - 0.5).astype(np.float32)
        # cv2.remap: pixel centres at integer coordinates, as in CONVENTIONS.md. Its maps must have fewer
        # than 32767 rows and columns, so the N lookups go in as a (ceil(N / 4096), 4096) map.
        n = len(pb)
        cols = 4096
        rows = max(1, -(-n // cols))
        cu = np.zeros(rows * cols, np.float32)
        cv = np.zeros(rows * cols, np.float32)
        cu[:n], cv[:n] = c, r
        v = cv2.remap(self.texture, cu.reshape(rows, cols), cv.reshape(rows, cols), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out = v.reshape(-1)[:n].astype(np.float64)
        return self.albedo * out


Primitive = Union[Plane, Box, Cylinder, Cone, Sphere, TexturedPlane]


@dataclass(frozen=True, eq=False)
class Scene:
    """A list of objects; an object's id is its index in `objects` (the Truth.object_id values)."""

    objects: Sequence[Primitive] = ()

    def __post_init__(self) -> None:
        objs = tuple(self.objects)
        for k, ob in enumerate(objs):
            if not hasattr(ob, "intersect") or not hasattr(ob, "albedo_at"):
                raise ValueError(f"Scene.objects[{k}] is a {type(ob).__name__}, not a primitive (Plane, Box, …)")
        if len(objs) > np.iinfo(np.int16).max:
            raise ValueError("a Scene holds at most 32767 objects")
        object.__setattr__(self, "objects", objs)


def _candidates(bound, o: np.ndarray, d: np.ndarray, d_norm: np.ndarray) -> np.ndarray | None:
    """Rows whose ray can meet the bounding sphere (a conservative cull); None means all rows.

    With one shared origin this is a cone test, (d · u) >= |d| cos α with u the unit direction to the
    sphere's centre and α its angular radius: one matrix–vector product per object.
    """
    if bound is None:
        return None
    c, r = bound
    r = r * (1 + 1e-9) + 1e-6
    if len(o) == 1:
        oc = c - o[0]
        dist = float(np.linalg.norm(oc))
        if dist <= r:
            return None
        cos_a = np.sqrt(max(0.0, 1.0 - (r / dist) ** 2))
        return (d @ (oc / dist)) >= d_norm * (cos_a * (1 - 1e-12))
    oc = c - o
    b = np.einsum("ij,ij->i", oc, d)
    cc = np.einsum("ij,ij->i", oc, oc) - r * r
    disc = b * b - d_norm * d_norm * cc
    return (disc >= 0) & ((b > 0) | (cc <= 0))


def intersect_scene(
    scene: Scene, o: np.ndarray, d: np.ndarray, *, t_min: float = 0.0, skip_id: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hit of each ray with the scene.

    o: (N, 3) or (3,) origins, d: (N, 3) directions (world frame, mm). skip_id (N,), optional: an object
    each ray ignores. Returns t (N,) (inf: no hit), n (N, 3) the unit normal at the hit turned to face the
    ray's origin (NaN: no hit), and object_id (N,) int16 (−1: no hit).
    """
    d = np.asarray(d, np.float64).reshape(-1, 3)
    o = np.asarray(o, np.float64).reshape(-1, 3)
    N = len(d)
    d_norm = np.sqrt((d * d).sum(axis=1))
    t_best = np.full(N, np.inf)
    n_best = _nan_normals(N)
    oid = np.full(N, -1, np.int16)
    for k, ob in enumerate(scene.objects):
        cand = _candidates(ob.bound(), o, d, d_norm)
        if skip_id is not None:
            cand = (skip_id != k) if cand is None else cand & (skip_id != k)
        if cand is None:
            t, n = ob.intersect(o, d, t_min=t_min)
            closer = t < t_best
            t_best[closer] = t[closer]
            n_best[closer] = n[closer]
            oid[closer] = k
            continue
        rows = np.flatnonzero(cand)
        if len(rows) == 0:
            continue
        t, n = ob.intersect(o if len(o) == 1 else o[rows], d[rows], t_min=t_min)
        closer = t < t_best[rows]
        sel = rows[closer]
        t_best[sel] = t[closer]
        n_best[sel] = n[closer]
        oid[sel] = k
    hit = oid >= 0
    facing_away = (n_best * d).sum(axis=1) > 0
    n_best[hit & facing_away] *= -1
    return t_best, n_best, oid


def segment_blocked(scene: Scene, p_from: np.ndarray, p_to: np.ndarray, *, skip_id: np.ndarray) -> np.ndarray:
    """Whether the open segment between each p_from (N, 3) and the single point p_to (3,) meets any object
    other than skip_id[i] (the object p_from lies on). Returns (N,) bool.

    The segments are cast from p_to (e.g. the projector centre) towards each p_from, so they share one
    origin and the cheap cone cull applies; blocked means a hit at t < 1 (before reaching p_from).
    """
    p_from = np.asarray(p_from, np.float64).reshape(-1, 3)
    p_to = np.asarray(p_to, np.float64).reshape(3)
    d = p_from - p_to
    t, _, _ = intersect_scene(scene, p_to, d, t_min=1e-9, skip_id=np.asarray(skip_id).reshape(-1))
    return t < 1 - 1e-9
