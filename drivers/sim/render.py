"""Rendering: what the camera sees of the scene lit by a projector image, and the per-pixel truth.

The model (docs/simulator.md):

    radiance = albedo · (ambient + projector_gain · cos θ_p · P(q_proj) · lit)
    grey     = full_scale · box_mean(radiance over the supersamples) ^ (1 / gamma) + noise

P is the projector image (0…1) sampled bilinearly at the projector pixel q_proj the surface point maps to
(pixel centres at integer coordinates, CONVENTIONS.md); θ_p is the angle between the surface normal and
the direction to the projector centre; `lit` says the projector sees the point (inside its image, surface
facing it, segment to its centre free). There is no inverse-square fall-off and no inter-reflection.
Anti-aliasing: s × s camera rays per pixel through the offsets (k + ½)/s − ½, k = 0…s−1, symmetric about
the pixel centre, so a line's intensity profile is not shifted (docs/decisions/0012-sim-supersampling.md).

Geometry (camera rays, intersections, shadows, projector coordinates) does not depend on the projector
image, so `Geometry` computes it once; each new pattern then costs one `cv2.remap` of the projector image
plus shading, averaging and noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from calibration.models import Intrinsics, ProCam
from drivers.sim.scene import Scene, TexturedPlane, intersect_scene, segment_blocked

_CHUNK = 1 << 18  # rays per batch: bounds the temporary memory (~100 MB) of the ray caster


@dataclass(frozen=True)
class RenderOptions:
    """How an image is formed.

    noise_grey: standard deviation of the additive Gaussian sensor noise, in 8-bit grey levels (scaled by
    257 for 16-bit output). ambient: ambient irradiance as a fraction of full scale (reaches shadows too).
    gamma: camera response exponent, grey ∝ radiance^(1/gamma) (1: linear). bit_depth: 8 (uint8) or 16
    (uint16). projector_gain: radiance of a full-white projector pixel on an albedo-1 surface facing the
    projector. supersample: rays per pixel along each axis (anti-aliasing); 1 = one ray per pixel centre.
    """

    noise_grey: float = 1.0
    ambient: float = 0.05
    gamma: float = 1.0
    bit_depth: Literal[8, 16] = 8
    projector_gain: float = 0.9
    supersample: int = 3

    def __post_init__(self) -> None:
        problems = []
        if not self.noise_grey >= 0:
            problems.append(f"noise_grey must be >= 0, got {self.noise_grey}")
        if not 0 <= self.ambient <= 1:
            problems.append(f"ambient must be in [0, 1], got {self.ambient}")
        if not self.gamma > 0:
            problems.append(f"gamma must be > 0, got {self.gamma}")
        if self.bit_depth not in (8, 16):
            problems.append(f"bit_depth must be 8 or 16, got {self.bit_depth}")
        if not self.projector_gain >= 0:
            problems.append(f"projector_gain must be >= 0, got {self.projector_gain}")
        if not (isinstance(self.supersample, int) and 1 <= self.supersample <= 8):
            problems.append(f"supersample must be an integer 1…8, got {self.supersample}")
        if problems:
            raise ValueError("RenderOptions: " + "; ".join(problems))


@dataclass(frozen=True, eq=False)
class Truth:
    """Ground truth per camera pixel (the ray through the pixel centre); arrays (H, W, …).

    p_proj (H, W, 3) float32: surface point, world = projector frame, mm; NaN where the ray meets nothing.
    depth_cam (H, W) float32: its camera-frame z, mm; NaN likewise.
    normal_proj (H, W, 3) float32: unit surface normal (world frame), turned towards the camera; NaN.
    object_id (H, W) int16: index into Scene.objects, −1 for nothing.
    q_proj (H, W, 2) float32: projector pixel (u, v) the point maps to; NaN if no surface, behind the
        projector or outside its image (u, v in [−½, W−½] × [−½, H−½]). Shadowed points keep their q_proj.
    lit (H, W) bool: the projector sees the point (inside its image, surface facing it, not shadowed).
    """

    p_proj: np.ndarray
    depth_cam: np.ndarray
    normal_proj: np.ndarray
    object_id: np.ndarray
    q_proj: np.ndarray
    lit: np.ndarray

    FIELDS = ("p_proj", "depth_cam", "normal_proj", "object_id", "q_proj", "lit")

    def as_dict(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in self.FIELDS}

    @classmethod
    def from_dict(cls, data) -> "Truth":
        """From `np.load("truth.npz")` or `as_dict()`."""
        return cls(**{k: np.asarray(data[k]) for k in cls.FIELDS})


def _sample_grid(width: int, height: int, s: int) -> np.ndarray:
    """Camera subsample positions (height·s · width·s, 2), row-major: offsets (k + ½)/s − ½ around each
    pixel centre, i.e. a uniform grid at (index + ½)/s − ½."""
    u = (np.arange(width * s) + 0.5) / s - 0.5
    v = (np.arange(height * s) + 0.5) / s - 0.5
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def _projector_limits(projector: Intrinsics) -> float:
    """Largest squared normalised radius a point may have to be inside the projector image.

    OpenCV's polynomial distortion folds back beyond some radius: a point far outside the field of view
    can land inside the image. Points farther off-axis than 1.25× the image border are rejected first.
    """
    w, h = projector.width, projector.height
    k = 64
    border = np.concatenate(
        [
            np.column_stack([np.linspace(-0.5, w - 0.5, k), np.full(k, -0.5)]),
            np.column_stack([np.linspace(-0.5, w - 0.5, k), np.full(k, h - 0.5)]),
            np.column_stack([np.full(k, -0.5), np.linspace(-0.5, h - 0.5, k)]),
            np.column_stack([np.full(k, w - 0.5), np.linspace(-0.5, h - 0.5, k)]),
        ]
    )
    xy = projector.pixels_to_normalised(border)
    return float((1.25 * np.sqrt((xy**2).sum(axis=1).max())) ** 2)


_LIMITS: dict[int, tuple[Intrinsics, float]] = {}


def _projector_limits_cached(projector: Intrinsics) -> float:
    hit = _LIMITS.get(id(projector))
    if hit is None or hit[0] is not projector:
        if len(_LIMITS) > 64:
            _LIMITS.clear()
        hit = _LIMITS[id(projector)] = (projector, _projector_limits(projector))
    return hit[1]


def project_to_projector(projector: Intrinsics, p_proj: np.ndarray, *, r2_max: float | None = None) -> np.ndarray:
    """World points (N, 3) -> projector pixels (N, 2); NaN behind the projector, outside its image or
    beyond the distortion model's fold-back radius."""
    if r2_max is None:
        r2_max = _projector_limits_cached(projector)
    p = np.asarray(p_proj, np.float64).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = p[:, :2] / p[:, 2:3]
        ok = (p[:, 2] > 0) & ((xy**2).sum(axis=1) <= r2_max)
    q = np.full((len(p), 2), np.nan)
    if ok.any():
        q[ok] = projector.project(p[ok])
    w, h = projector.width, projector.height
    with np.errstate(invalid="ignore"):
        inside = (q[:, 0] >= -0.5) & (q[:, 0] <= w - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= h - 0.5)
    q[~inside] = np.nan
    return q


def cast_rays(procam: ProCam, scene: Scene, q_cam: np.ndarray) -> dict[str, np.ndarray]:
    """Trace the camera rays through pixel positions q_cam (N, 2) into the scene.

    Returns arrays over N: p_proj (N, 3), normal_proj (N, 3) (facing the camera), object_id (N,) int16,
    depth_cam (N,), q_proj (N, 2) (NaN outside the projector image), cos_proj (N,) (cosine between the
    normal and the direction to the projector; 0 where unlit), lit (N,) bool, albedo (N,) (0 where nothing).
    """
    q_cam = np.asarray(q_cam, np.float64).reshape(-1, 2)
    parts = [_cast_chunk(procam, scene, q_cam[lo : lo + _CHUNK]) for lo in range(0, len(q_cam), _CHUNK)]
    if len(parts) == 1:
        return parts[0]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _cast_chunk(procam: ProCam, scene: Scene, q_cam: np.ndarray) -> dict[str, np.ndarray]:
    R, t_cam = procam.R_proj_cam, procam.t_proj_cam
    d_cam = procam.camera.rays(q_cam)  # z = 1 in the camera frame, so t is the camera depth
    d = d_cam @ R.T
    t, n, oid = intersect_scene(scene, t_cam, d, t_min=1e-6)
    hit = oid >= 0
    with np.errstate(invalid="ignore"):
        p = t_cam + np.where(hit, t, np.nan)[:, None] * d
    q = project_to_projector(procam.projector, p)
    dist = np.sqrt((p * p).sum(axis=1))
    with np.errstate(invalid="ignore"):
        cos = -(n * p).sum(axis=1) / dist  # the direction to the projector centre is −p/|p|
        can = hit & np.isfinite(q[:, 0]) & (cos > 0)
    lit = can.copy()
    if can.any():
        lit[can] = ~segment_blocked(scene, p[can], np.zeros(3), skip_id=oid[can])
    albedo = np.zeros(len(p))
    for k in np.unique(oid[hit]):
        m = oid == k
        albedo[m] = scene.objects[k].albedo_at(p[m])
    return {
        "p_proj": p,
        "normal_proj": n,
        "object_id": oid,
        "depth_cam": np.where(hit, t, np.nan),
        "q_proj": q,
        "cos_proj": np.where(lit, cos, 0.0),
        "lit": lit,
        "albedo": albedo,
    }


def _as_unit_image(projector_image: np.ndarray, projector: Intrinsics) -> np.ndarray:
    img = np.asarray(projector_image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = img[..., :3].mean(axis=2).astype(img.dtype)
    if img.shape != (projector.height, projector.width):
        raise ValueError(
            f"projector image is {img.shape[1] if img.ndim > 1 else '?'}x{img.shape[0]} (WxH), but the projector is "
            f"{projector.width}x{projector.height}: render the pattern at the projector's resolution"
        )
    if img.dtype == np.uint8:
        return img.astype(np.float32) * np.float32(1 / 255)
    if img.dtype == np.uint16:
        return img.astype(np.float32) * np.float32(1 / 65535)
    if img.dtype == bool:
        return img.astype(np.float32)
    return np.clip(img.astype(np.float32), 0, 1)


class Geometry:
    """Everything about one rig + scene that does not depend on the projector image.

    Built once (the expensive part: s² rays per camera pixel, intersections, shadow segments); `shade`
    then renders any projector image.
    """

    def __init__(self, procam: ProCam, scene: Scene, *, supersample: int = 3, adaptive: bool = True) -> None:
        cam = procam.camera
        self.procam = procam
        self.scene = scene
        self.supersample = s = int(supersample)
        H, W = cam.height, cam.width
        # Truth: one ray through each pixel centre.
        centre = cast_rays(procam, scene, cam.pixel_grid())
        q_t = centre["q_proj"].reshape(H, W, 2)
        self.truth = Truth(
            p_proj=centre["p_proj"].reshape(H, W, 3).astype(np.float32),
            depth_cam=centre["depth_cam"].reshape(H, W).astype(np.float32),
            normal_proj=centre["normal_proj"].reshape(H, W, 3).astype(np.float32),
            object_id=centre["object_id"].reshape(H, W),
            q_proj=q_t.astype(np.float32),
            lit=centre["lit"].reshape(H, W),
        )
        for a in self.truth.as_dict().values():
            a.setflags(write=False)
        # Shading samples: s × s per pixel, as maps of shape (H·s, W·s) (sample (ky, kx) of pixel (v, u)
        # at [v·s + ky, u·s + kx]).
        Hs, Ws = H * s, W * s
        self._map_u = np.full((Hs, Ws), -10.0, np.float32)  # unlit samples look far outside the image
        self._map_v = np.full((Hs, Ws), -10.0, np.float32)
        self._weight = np.zeros((Hs, Ws), np.float32)
        albedo = np.zeros((Hs, Ws), np.float32)
        if s == 1:
            exact = np.ones((H, W), bool)
        elif adaptive:
            exact = ~self._fill_smooth(centre, albedo)
        else:
            exact = np.ones((H, W), bool)
        self.exact_fraction = float(exact.mean())
        self._fill_exact(centre, exact, albedo)
        self._albedo_px = self._box_mean(albedo)

    def _views(self, *arrays: np.ndarray) -> list[np.ndarray]:
        """(H·s, W·s) maps seen as (H, s, W, s)."""
        H, W, s = self.procam.camera.height, self.procam.camera.width, self.supersample
        return [a.reshape(H, s, W, s) for a in arrays]

    def _fill_smooth(self, centre: dict[str, np.ndarray], albedo: np.ndarray) -> np.ndarray:
        """Fill the samples of pixels whose 3 × 3 neighbourhood is one smooth, uniformly lit (or unlit)
        untextured surface, by a first-order expansion of the centre rays' projector coordinates and
        shading weight (central differences); returns that mask. The expansion is symmetric about the
        pixel centre like the rays it replaces; its error is second order in the subsample offset
        (docs/decisions/0012-sim-supersampling.md)."""
        H, W, s = self.procam.camera.height, self.procam.camera.width, self.supersample
        oid = centre["object_id"].reshape(H, W)
        lit = centre["lit"].reshape(H, W)
        n = centre["normal_proj"].reshape(H, W, 3)
        q = centre["q_proj"].reshape(H, W, 2)
        w = (centre["albedo"] * centre["cos_proj"]).reshape(H, W)
        alb = centre["albedo"].reshape(H, W)
        textured = np.zeros(len(self.scene.objects) + 1, bool)
        for k, ob in enumerate(self.scene.objects):
            textured[k] = isinstance(ob, TexturedPlane)
        smooth = np.zeros((H, W), bool)
        if H < 3 or W < 3:
            return smooth
        c = (slice(1, H - 1), slice(1, W - 1))
        oc, lc, nc = oid[c], lit[c], n[c]
        core = ~textured[oc]
        with np.errstate(invalid="ignore"):
            for dv in (-1, 0, 1):
                for du in (-1, 0, 1):
                    if dv == du == 0:
                        continue
                    nb = (slice(1 + dv, H - 1 + dv), slice(1 + du, W - 1 + du))
                    same_surface = (oid[nb] == oc) & (lit[nb] == lc) & ((n[nb] * nc).sum(axis=2) > 0.98)
                    core &= same_surface | ((oid[nb] == -1) & (oc == -1))
        # The first-order expansion must be accurate: its error is about |f''|·δ²/2 with δ <= ½ px, so
        # bound the second differences of q_proj (0.09 px: <= 0.005 projector px at s = 3) and of the
        # weight, and the mixed difference (0.045 px), where the pixel is lit.
        with np.errstate(invalid="ignore"):
            q_uu = np.abs(q[1:-1, 2:] - 2 * q[1:-1, 1:-1] + q[1:-1, :-2]).max(axis=2)
            q_vv = np.abs(q[2:, 1:-1] - 2 * q[1:-1, 1:-1] + q[:-2, 1:-1]).max(axis=2)
            q_uv = np.abs(q[2:, 2:] - q[2:, :-2] - q[:-2, 2:] + q[:-2, :-2]).max(axis=2) / 4
            w_2 = np.maximum(np.abs(w[1:-1, 2:] - 2 * w[1:-1, 1:-1] + w[1:-1, :-2]), np.abs(w[2:, 1:-1] - 2 * w[1:-1, 1:-1] + w[:-2, 1:-1]))
            linear = (q_uu <= 0.09) & (q_vv <= 0.09) & (q_uv <= 0.045) & (w_2 <= 0.02)
        smooth[c] = core & (~lc | linear)
        offs = ((np.arange(s) + 0.5) / s - 0.5).astype(np.float32)
        dq_du = np.zeros_like(q)
        dq_dv = np.zeros_like(q)
        dq_du[:, 1:-1] = (q[:, 2:] - q[:, :-2]) / 2
        dq_dv[1:-1] = (q[2:] - q[:-2]) / 2
        dw_du = np.zeros_like(w)
        dw_dv = np.zeros_like(w)
        dw_du[:, 1:-1] = (w[:, 2:] - w[:, :-2]) / 2
        dw_dv[1:-1] = (w[2:] - w[:-2]) / 2
        use = smooth & lit
        mu, mv, wt, al = self._views(self._map_u, self._map_v, self._weight, albedo)
        for ky in range(s):
            for kx in range(s):
                du, dv = offs[kx], offs[ky]
                mu[:, ky, :, kx] = np.where(use, q[..., 0] + dq_du[..., 0] * du + dq_dv[..., 0] * dv, mu[:, ky, :, kx])
                mv[:, ky, :, kx] = np.where(use, q[..., 1] + dq_du[..., 1] * du + dq_dv[..., 1] * dv, mv[:, ky, :, kx])
                wt[:, ky, :, kx] = np.where(use, np.maximum(w + dw_du * du + dw_dv * dv, 0), wt[:, ky, :, kx])
                al[:, ky, :, kx] = np.where(smooth, alb, al[:, ky, :, kx])
        return smooth

    def _fill_exact(self, centre: dict[str, np.ndarray], exact: np.ndarray, albedo: np.ndarray) -> None:
        """Cast s × s rays through each pixel marked in `exact` (H, W) and fill their samples."""
        H, W, s = self.procam.camera.height, self.procam.camera.width, self.supersample
        if s == 1:
            lit = centre["lit"].reshape(H, W)
            q = centre["q_proj"].reshape(H, W, 2)
            self._map_u[lit] = q[..., 0][lit]
            self._map_v[lit] = q[..., 1][lit]
            self._weight[:] = (centre["albedo"] * centre["cos_proj"]).reshape(H, W)
            albedo[:] = centre["albedo"].reshape(H, W)
            return
        vv, uu = np.nonzero(exact)
        offs = (np.arange(s) + 0.5) / s - 0.5
        ky, kx = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
        ky, kx = ky.ravel(), kx.ravel()
        per_block = max(1, _CHUNK // (s * s))
        mu, mv, wt, al = self._views(self._map_u, self._map_v, self._weight, albedo)
        for lo in range(0, len(vv), per_block):
            v = vv[lo : lo + per_block, None]
            u = uu[lo : lo + per_block, None]
            qs = np.column_stack([(u + offs[kx]).ravel(), (v + offs[ky]).ravel()])
            part = _cast_chunk(self.procam, self.scene, qs)
            V = np.broadcast_to(v, (len(v), s * s)).ravel()
            U = np.broadcast_to(u, (len(u), s * s)).ravel()
            KY = np.tile(ky, len(v))
            KX = np.tile(kx, len(v))
            lit = part["lit"]
            mu[V[lit], KY[lit], U[lit], KX[lit]] = part["q_proj"][lit, 0]
            mv[V[lit], KY[lit], U[lit], KX[lit]] = part["q_proj"][lit, 1]
            wt[V, KY, U, KX] = part["albedo"] * part["cos_proj"]
            al[V, KY, U, KX] = part["albedo"]

    def _box_mean(self, a: np.ndarray) -> np.ndarray:
        if self.supersample == 1:
            return a
        H, W = self.procam.camera.height, self.procam.camera.width
        # cv2.resize takes (W, H); INTER_AREA with an integer factor is the exact s × s block mean.
        return cv2.resize(a, (W, H), interpolation=cv2.INTER_AREA)

    def radiance(self, projector_image: np.ndarray | None, *, ambient: float, projector_gain: float) -> np.ndarray:
        """Linear radiance per camera pixel (H, W) float32 (1 = full scale), before gamma, noise, quantisation."""
        base = self._albedo_px * np.float32(ambient)
        if projector_image is None or projector_gain == 0:
            return base.copy()
        P = _as_unit_image(projector_image, self.procam.projector)
        lookup = cv2.remap(P, self._map_u, self._map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        lookup *= self._weight
        out = self._box_mean(lookup)
        out *= np.float32(projector_gain)
        out += base
        return out

    def shade(self, projector_image: np.ndarray | None, *, options: RenderOptions, rng: np.random.Generator) -> np.ndarray:
        """The camera image (H, W), uint8 or uint16 per options.bit_depth."""
        lin = self.radiance(projector_image, ambient=options.ambient, projector_gain=options.projector_gain)
        np.clip(lin, 0, 1, out=lin)
        if options.gamma != 1:
            lin **= np.float32(1 / options.gamma)
        full = 255.0 if options.bit_depth == 8 else 65535.0
        lin *= np.float32(full)
        if options.noise_grey > 0:
            noise = rng.standard_normal(lin.shape, dtype=np.float32)
            noise *= np.float32(options.noise_grey * full / 255.0)
            lin += noise
        np.rint(lin, out=lin)
        np.clip(lin, 0, full, out=lin)
        return lin.astype(np.uint8 if options.bit_depth == 8 else np.uint16)


def render(
    procam: ProCam,
    scene: Scene,
    projector_image: np.ndarray | None,
    *,
    options: RenderOptions = RenderOptions(),
    rng: np.random.Generator,
) -> tuple[np.ndarray, Truth]:
    """Render one camera image of `scene` lit by `projector_image` ((Hp, Wp) at the projector's
    resolution, uint8; None = dark), and the per-pixel truth. To render many patterns of one rig, use
    SimWorld (the geometry is computed once)."""
    geo = Geometry(procam, scene, supersample=options.supersample)
    return geo.shade(projector_image, options=options, rng=rng), geo.truth
