"""Gray-code structured light: pattern generation and robust per-pixel decoding.

Pattern order is OpenCV's `structured_light.GrayCodePattern` (the layout other tools share): for each
column bit, most significant first, the pattern then its inverse; then the same for the row bits; then
a white and a black image. A projector of width W and height H uses ceil(log2 W) column bits and
ceil(log2 H) row bits: 1024x768 -> 10 + 10 bits -> 2 * 20 + 2 = 42 images. In the bit images, projector
pixel column u is lit where bit k of the Gray code g(u) = u ^ (u >> 1) is 1.

Decoding (`decode_graycode`) follows Moreno & Taubin (2012, "Simple, accurate, and robust projector-camera
calibration", robust pixel classification of Xu & Aliaga): the black image is subtracted (ambient light,
projector black level); each pixel's direct and global light are separated (Nayar et al. 2006) from
mid-to-high-frequency bit pairs; pixels with too little direct light (shadows, black board squares, outside
the projection) are invalid; each bit is decided by comparing the pattern with its inverse, which is
independent of gamma and of any global offset; where global light dominates a bit is accepted only when
the evidence is unambiguous. Decoded codes outside the projector or inconsistent with their neighbours
(3x3 median) are invalid.

The decoded projector coordinate is the integer pixel index: projector pixel column u has its centre at
u (CONVENTIONS.md), so `u_proj` is the centre of the projector pixel that lit the camera pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from calibration.errors import CalibrationError


def graycode_bits(n_pixels: int) -> int:
    """Number of Gray-code bits for `n_pixels` columns (or rows): ceil(log2 n), at least 1."""
    if n_pixels < 2:
        raise ValueError(f"need at least 2 projector pixels per direction, got {n_pixels}")
    return int(np.ceil(np.log2(n_pixels)))


def graycode_pattern_count(width: int, height: int) -> int:
    """Number of images `graycode_patterns(width, height)` returns: 2 * (column bits + row bits) + 2."""
    return 2 * (graycode_bits(width) + graycode_bits(height)) + 2


def _gray(n: np.ndarray) -> np.ndarray:
    return n ^ (n >> 1)


def _gray_to_binary(g: np.ndarray) -> np.ndarray:
    b = g.copy()
    shift = 1
    while shift < 32:
        b ^= b >> shift
        shift *= 2
    return b


def graycode_patterns(width: int, height: int, *, white: int = 255, black: int = 0) -> list[np.ndarray]:
    """The projector images, each (height, width) uint8, in OpenCV's GrayCodePattern order + white, black.

    Index 2k is column bit k (most significant first), 2k + 1 its inverse; then the row bits the same way
    from index 2 * column_bits; the last two are white and black.
    """
    nc, nr = graycode_bits(width), graycode_bits(height)
    g_u = _gray(np.arange(width))
    g_v = _gray(np.arange(height))
    out: list[np.ndarray] = []
    for k in range(nc):
        lit = ((g_u >> (nc - 1 - k)) & 1).astype(bool)
        row = np.where(lit, white, black).astype(np.uint8)
        img = np.broadcast_to(row, (height, width)).copy()
        out += [img, np.where(lit, black, white).astype(np.uint8)[None, :].repeat(height, 0)]
    for k in range(nr):
        lit = ((g_v >> (nr - 1 - k)) & 1).astype(bool)
        col = np.where(lit, white, black).astype(np.uint8)[:, None]
        inv = np.where(lit, black, white).astype(np.uint8)[:, None]
        out += [np.broadcast_to(col, (height, width)).copy(), np.broadcast_to(inv, (height, width)).copy()]
    out.append(np.full((height, width), white, np.uint8))
    out.append(np.full((height, width), black, np.uint8))
    return out


@dataclass(frozen=True, eq=False)
class GrayCodeDecoding:
    """The result of `decode_graycode` for one camera view.

    u_proj, v_proj: (H, W) int32 projector pixel column / row seen by each camera pixel (-1 where invalid).
    valid: (H, W) bool. direct, global_: (H, W) float32 direct and global light (8-bit grey levels, black
    image subtracted). min_direct: the threshold on `direct` that was used (automatic unless given).
    """

    u_proj: np.ndarray
    v_proj: np.ndarray
    valid: np.ndarray
    direct: np.ndarray
    global_: np.ndarray
    min_direct: float

    @property
    def valid_fraction(self) -> float:
        return float(self.valid.mean())


def _to_float(img: np.ndarray) -> np.ndarray:
    a = np.asarray(img)
    if a.ndim == 3:
        a = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY) if a.shape[2] == 3 else a[..., 0]
    if a.dtype == np.uint16:
        return a.astype(np.float32) * np.float32(255.0 / 65535.0)
    return a.astype(np.float32)


def _otsu(values: np.ndarray) -> float:
    v = np.clip(values, 0, 255).astype(np.uint8)
    thr, _ = cv2.threshold(v.reshape(1, -1), 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    return float(thr)


def decode_graycode(
    images: Sequence[np.ndarray],
    *,
    projector_width: int,
    projector_height: int,
    min_direct: float | None = None,
    min_direct_floor: float = 5.0,
    max_jump_px: int = 2,
) -> GrayCodeDecoding:
    """Decode one view's Gray-code images into projector coordinates per camera pixel.

    images: the camera images in `graycode_patterns` order ((H, W) uint8 or uint16, or BGR), all one size.
    projector_width, projector_height: the projector's resolution the patterns were made for.
    min_direct: direct light (grey levels, 8-bit scale) below which a pixel is invalid; None chooses it
    automatically: Otsu's split between lit and unlit pixels, at most a quarter of the 99th percentile
    of the direct light, at least `min_direct_floor`.
    max_jump_px: a pixel whose code differs from its 3x3 median by more than this is invalid.
    Raises CalibrationError for a wrong number of images or images of different sizes.
    """
    nc, nr = graycode_bits(projector_width), graycode_bits(projector_height)
    expected = 2 * (nc + nr) + 2
    if len(images) != expected:
        raise CalibrationError(
            f"a Gray code for a {projector_width}x{projector_height} projector has {expected} images "
            f"({nc} column bits, {nr} row bits, each with its inverse, then white and black), got {len(images)}: "
            "check --projector-size and that every pattern was captured"
        )
    shapes = {np.asarray(im).shape[:2] for im in images}
    if len(shapes) != 1:
        raise CalibrationError(f"the Gray-code images of one view differ in size ({sorted(shapes)}); capture them again with one camera setting")
    black = _to_float(images[-1])

    def pair(i: int) -> tuple[np.ndarray, np.ndarray]:
        return _to_float(images[i]) - black, _to_float(images[i + 1]) - black

    # Direct / global separation from bit pairs with 8..32 projector-pixel stripes (bits 2..4 counted from
    # the least significant): fine enough for Nayar's high-frequency condition on ordinary scenes, coarse
    # enough to survive defocus and a camera with fewer pixels than the projector.
    sep_bits = [(0, nc, k) for k in range(max(0, nc - 5), max(1, nc - 2))] + [(2 * nc, nr, k) for k in range(max(0, nr - 5), max(1, nr - 2))]
    l_max = np.full(black.shape, -np.inf, np.float32)
    l_min = np.full(black.shape, np.inf, np.float32)
    for base, _n, k in sep_bits:
        p, q = pair(base + 2 * k)
        np.maximum(l_max, np.maximum(p, q), out=l_max)
        np.minimum(l_min, np.minimum(p, q), out=l_min)
    direct = np.maximum(l_max - l_min, 0)
    global_ = np.maximum(2 * l_min, 0)
    if min_direct is None:
        # Otsu splits lit from unlit pixels when both are present; when (nearly) everything is lit the
        # histogram is unimodal and Otsu would cut it in half, hence the cap at a quarter of the brightest.
        min_direct = max(min_direct_floor, min(_otsu(direct), 0.25 * float(np.percentile(direct, 99))))
    valid = direct >= min_direct

    codes = []
    for base, n in ((0, nc), (2 * nc, nr)):
        g = np.zeros(black.shape, np.int32)
        for k in range(n):
            p, q = pair(base + 2 * k)
            bit = p > q
            # Moreno & Taubin's robust classification where global light dominates the direct light.
            weak = direct <= global_
            sure0 = (p <= direct) & (q >= global_)
            sure1 = (p >= global_) & (q <= direct)
            valid &= ~weak | sure0 | sure1
            bit = np.where(weak, sure1, bit)
            g |= bit.astype(np.int32) << (n - 1 - k)
        codes.append(_gray_to_binary(g))
    u, v = codes
    valid &= (u < projector_width) & (v < projector_height)
    for c in (u, v):
        med = cv2.medianBlur(np.where(valid, c, 0).astype(np.uint16), 3).astype(np.int32)
        valid &= np.abs(c - med) <= max_jump_px
    u = np.where(valid, u, -1).astype(np.int32)
    v = np.where(valid, v, -1).astype(np.int32)
    return GrayCodeDecoding(u, v, valid, direct.astype(np.float32), global_.astype(np.float32), float(min_direct))


def check_decodes(dec: GrayCodeDecoding, *, name: str, min_fraction: float = 0.01) -> None:
    """CalibrationError when (almost) nothing decoded: the usual causes and what to capture instead."""
    if dec.valid_fraction < min_fraction:
        raise CalibrationError(
            f"{name}: the Gray code does not decode ({100 * dec.valid_fraction:.1f} % of the camera pixels valid): "
            "check that the projector lights the board, that the frames are in pattern order (pattern, inverse, "
            "columns then rows, then white and black), that each frame was exposed after its pattern was shown "
            "(settle time) and that the camera is not saturated; capture the pose again"
        )
