"""The projected grid: its geometry (the paper's Eq. 1) and its image.

Coordinates: projector pixels relative to `centre_px` (x right, y down), see CONVENTIONS.md.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator


class GridPattern(BaseModel):
    """Two families of straight lines: i-lines y = tan(alpha1)·x + i·pitch, j-lines y = tan(alpha2)·x + j·pitch."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["grid"] = "grid"
    alpha1_deg: float = 30.0
    alpha2_deg: float = 120.0
    pitch_px: float = Field(30.0, gt=0)
    lines: int = Field(33, ge=2, le=1001)
    line_width_px: float = Field(3.0, gt=0)
    centre_px: tuple[float, float] = (511.5, 511.5)
    spacing: Literal["uniform", "debruijn"] = "uniform"

    @model_validator(mode="after")
    def _angles(self) -> "GridPattern":
        for name, a in (("alpha1_deg", self.alpha1_deg), ("alpha2_deg", self.alpha2_deg)):
            if abs(np.cos(np.deg2rad(a))) < 1e-3:
                raise ValueError(f"{name} = {a}: vertical lines cannot be written y = tan(a)·x + c; tilt them slightly")
        if abs(self.n1 - self.n2) < 1e-3:
            raise ValueError("alpha1_deg and alpha2_deg give parallel families; they must cross")
        return self

    # --- geometry -----------------------------------------------------------------------------------------
    @property
    def n1(self) -> float:
        return float(np.tan(np.deg2rad(self.alpha1_deg)))

    @property
    def n2(self) -> float:
        return float(np.tan(np.deg2rad(self.alpha2_deg)))

    @property
    def indices(self) -> np.ndarray:
        """Line indices of one family: −(lines−1)/2 … +(lines−1)/2 (integers; for even `lines` the upper half is one short)."""
        h = (self.lines - 1) // 2
        return np.arange(-h, -h + self.lines)

    def offsets_px(self, family: int) -> np.ndarray:
        """Offsets c of the lines y = n·x + c of family 1 (i) or 2 (j), in index order."""
        if family not in (1, 2):
            raise ValueError("family is 1 (i-lines) or 2 (j-lines)")
        if self.spacing == "debruijn":
            from reconstruction.debruijn import debruijn_offsets_px

            return debruijn_offsets_px(self.lines, self.pitch_px)
        return self.indices * self.pitch_px

    def junction_xy(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Junction positions (N, 2) relative to the centre for index arrays i, j (Eq. 1 of the paper)."""
        i = np.asarray(i, dtype=np.float64)
        j = np.asarray(j, dtype=np.float64)
        ci = np.interp(i, self.indices, self.offsets_px(1))
        cj = np.interp(j, self.indices, self.offsets_px(2))
        d = self.n2 - self.n1
        return np.column_stack([(ci - cj) / d, (self.n2 * ci - self.n1 * cj) / d])

    def junction_uv(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Junction positions (N, 2) in projector pixels."""
        return self.junction_xy(i, j) + np.asarray(self.centre_px)

    # --- image --------------------------------------------------------------------------------------------
    def render(self, width: int, height: int) -> np.ndarray:
        """The pattern as a uint8 (height, width) image: white anti-aliased lines on black.

        Each line is a box of `line_width_px` across, integrated over the pixel footprint along the
        normal (a linear ramp of one pixel at the edges).
        """
        v, u = np.mgrid[0:height, 0:width].astype(np.float32)
        x = u - np.float32(self.centre_px[0])
        y = v - np.float32(self.centre_px[1])
        img = np.zeros((height, width), np.float32)
        half = np.float32(self.line_width_px / 2)
        # Distance-like coordinate across each family: s_f = (y − n_f·x)/|(n_f, 1)|, so line c of family f
        # is s_f = c/|(n_f, 1)|. Each line is drawn only between its first and last junction (the grid is
        # the parallelogram of crossings), so every lit pixel belongs to a segment between two junctions.
        s = {}
        for family, n in ((1, self.n1), (2, self.n2)):
            s[family] = (y - np.float32(n) * x) / np.float32(np.hypot(n, 1.0))
        for family, n in ((1, self.n1), (2, self.n2)):
            other, n_other = (2, self.n2) if family == 1 else (1, self.n1)
            norm_o = np.hypot(n_other, 1.0)
            lo, hi = self.offsets_px(other)[[0, -1]] / norm_o
            extent = np.clip(np.minimum(s[other] - (lo - half), (hi + half) - s[other]) + 0.5, 0, 1)
            norm = np.float32(np.hypot(n, 1.0))
            for c in self.offsets_px(family):
                d = np.abs(s[family] - np.float32(c / norm))
                np.maximum(img, np.clip(half + 0.5 - d, 0, 1) * extent, out=img)
        return np.round(img * 255).astype(np.uint8)

    def fits(self, width: int, height: int) -> str | None:
        """None if every junction lies inside a width×height projector, else a sentence saying what does not fit."""
        ii, jj = np.meshgrid(self.indices, self.indices, indexing="ij")
        uv = self.junction_uv(ii.ravel(), jj.ravel())
        inside = (uv[:, 0] >= -0.5) & (uv[:, 0] <= width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= height - 0.5)
        if inside.all():
            return None
        return (
            f"the {self.lines}-line grid with pitch {self.pitch_px} px centred at {self.centre_px} puts "
            f"{int((~inside).sum())} of {inside.size} junctions outside the {width}x{height} projector; "
            "reduce pitch_px or lines, or move centre_px"
        )
