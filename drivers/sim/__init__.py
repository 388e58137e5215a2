"""The simulated rig: a ray-traced workspace lit by a pinhole projector and seen by a pinhole camera.

    rig = preset("tabletop")                    # SimRig: truth calibration + scene + depth range
    world = SimWorld(rig, options=RenderOptions(noise_grey=1.0), seed=0)
    image = world.render(pattern_image)         # geometry cached: each pattern costs a lookup + noise
    world.truth.p_proj                          # per-pixel ground truth

    with SimProjector(world) as proj, SimCamera(world, source=proj) as cam: …   # drivers.base interfaces

See docs/simulator.md.
"""

from drivers.sim.devices import SimCamera, SimProjector
from drivers.sim.output import write_simulation
from drivers.sim.presets import PRESETS, SimRig, preset
from drivers.sim.render import Geometry, RenderOptions, Truth, cast_rays, render
from drivers.sim.scene import Box, Cone, Cylinder, Plane, Scene, Sphere, TexturedPlane, intersect_scene, segment_blocked
from drivers.sim.world import SimWorld

__all__ = [
    "Box",
    "Cone",
    "Cylinder",
    "Geometry",
    "PRESETS",
    "Plane",
    "RenderOptions",
    "Scene",
    "SimCamera",
    "SimProjector",
    "SimRig",
    "SimWorld",
    "Sphere",
    "TexturedPlane",
    "Truth",
    "cast_rays",
    "intersect_scene",
    "preset",
    "render",
    "segment_blocked",
    "write_simulation",
]
