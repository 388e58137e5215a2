"""SimWorld: one simulated rig with its geometry computed once, shared by the simulated devices."""

from __future__ import annotations

import numpy as np

from calibration.models import ProCam
from drivers.sim.presets import SimRig
from drivers.sim.render import Geometry, RenderOptions, Truth


class SimWorld:
    """The virtual workspace that the simulated projector lights and the simulated camera looks at.

    The first render (or access to `geometry`/`truth`) ray-casts the scene once (camera rays, shadows, projector
    coordinates: a few seconds for 1280×1024 at supersample 3); each `render(image)` then costs one projector
    lookup, shading and noise. A world that only backs a simulated projector never pays for the ray casting.
    Noise comes from one generator seeded with `seed`, so a sequence of renders is reproducible.
    """

    def __init__(self, rig: SimRig, *, options: RenderOptions = RenderOptions(), seed: int = 0) -> None:
        self.rig = rig
        self.options = options
        self.seed = seed
        self._rng = np.random.default_rng(seed)
        self._geometry: Geometry | None = None

    @property
    def procam(self) -> ProCam:
        """The true calibration."""
        return self.rig.procam

    @property
    def geometry(self) -> Geometry:
        """The cached geometry (maps, weights; `exact_fraction` = share of pixels ray-cast at every subsample)."""
        if self._geometry is None:
            self._geometry = Geometry(self.rig.procam, self.rig.scene, supersample=self.options.supersample)
        return self._geometry

    @property
    def truth(self) -> Truth:
        """Per-pixel ground truth (read-only arrays)."""
        return self.geometry.truth

    def render(self, projector_image: np.ndarray | None) -> np.ndarray:
        """The camera image (H, W) (uint8 or uint16 per options.bit_depth) with the projector showing
        `projector_image` ((Hp, Wp) at the projector's resolution; None = dark)."""
        return self.geometry.shade(projector_image, options=self.options, rng=self._rng)

    def radiance(self, projector_image: np.ndarray | None) -> np.ndarray:
        """Noise-free linear radiance (H, W) float32, 1 = full scale, before gamma and quantisation."""
        o = self.options
        return self.geometry.radiance(projector_image, ambient=o.ambient, projector_gain=o.projector_gain)
