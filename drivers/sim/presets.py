"""Ready-made simulated rigs: the default tabletop rig and the paper's three camera configurations.

Each preset is a SimRig: the true calibration (ProCam, world = projector frame, mm), the scene, and the
camera-frame depth range the camera sees. The choices are explained in docs/simulator.md and
docs/decisions/0010-paper-presets.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import ConfigError
from calibration.models import Intrinsics, ProCam, look_at, rotation_from_euler_deg
from drivers.sim.render import cast_rays
from drivers.sim.scene import Box, Cone, Cylinder, Plane, Scene, Sphere

PRESETS: tuple[str, ...] = ("tabletop", "paper-parallel", "paper-intermediate", "paper-orthogonal")


@dataclass(frozen=True, eq=False)
class SimRig:
    """A simulated rig: `procam` is the truth it renders with; `depth_range_mm` = (near, far) camera-frame
    z of the surface points the camera sees and the projector lights (a ray cast every few pixels,
    widened by 2 %; see `depth_range`)."""

    name: str
    procam: ProCam
    scene: Scene
    depth_range_mm: tuple[float, float]
    description: str


def depth_range(procam: ProCam, scene: Scene, *, step_px: int = 4, margin: float = 0.02) -> tuple[float, float]:
    """(near, far) camera-frame z (mm) of the surfaces the camera sees *and* the projector lights (inside
    its image, facing it, not shadowed): the working volume where a pattern can be observed. From a ray
    cast every `step_px`-th pixel, widened by `margin` (fraction) on each side, rounded outwards to mm.
    Falls back to every surface seen if the projector lights none of them."""
    cam = procam.camera
    v, u = np.mgrid[0 : cam.height : step_px, 0 : cam.width : step_px]
    hits = cast_rays(procam, scene, np.column_stack([u.ravel(), v.ravel()]).astype(np.float64))
    z = hits["depth_cam"][hits["lit"]]
    if len(z) == 0:
        z = hits["depth_cam"][hits["object_id"] >= 0]
    if len(z) == 0:
        raise ConfigError("the simulated camera sees no part of the scene: check the truth calibration's pose")
    return float(np.floor(z.min() * (1 - margin))), float(np.ceil(z.max() * (1 + margin)))


# --------------------------------------------------------------------------------------------------------
# tabletop: the default rig of `rig scan`
# --------------------------------------------------------------------------------------------------------

TABLE_DISTANCE_MM = 850.0  # projector centre to the table along the projector axis
TABLE_TILT_DEG = 10.0  # the table recedes towards the top of the projector image


def tabletop_procam() -> ProCam:
    """A 1280×1024 camera (fx = fy = 2300 px, e.g. a 12 mm lens on 5.2 µm pixels) 306 mm beside a 1024×1024
    projector (f = 2400 px; the camera 300 mm to the right and 66 mm below), converged on the table
    centre; mild distortion on both."""
    camera = Intrinsics(
        1280, 1024, np.array([[2300.0, 0.0, 643.5], [0.0, 2300.0, 509.0], [0.0, 0.0, 1.0]]), np.array([-0.07, 0.12, 0.0004, -0.0003, 0.0])
    )
    projector = Intrinsics(
        1024, 1024, np.array([[2400.0, 0.0, 515.0], [0.0, 2400.0, 530.0], [0.0, 0.0, 1.0]]), np.array([0.02, -0.01, 0.0, 0.0, 0.0])
    )
    # The baseline is turned 12.4° from horizontal: with the default 30°/120° grid a horizontal baseline puts
    # junctions (i, j) and (i + 1, j − 3) on the same epipolar line (docs/decisions/0013-tabletop-baseline.md).
    t = np.array([300.0, 66.0, 0.0])
    R = look_at(t, np.array([0.0, 0.0, TABLE_DISTANCE_MM]))
    return ProCam(camera, projector, R, t)


def tabletop_scene() -> Scene:
    """A table tilted by 10° 850 mm in front of the projector with two boxes, a cylinder, a cone and a sphere."""
    tilt = np.deg2rad(TABLE_TILT_DEG)
    up = np.array([0.0, -np.sin(tilt), -np.cos(tilt)])  # table normal, towards the projector

    def on_table(x: float, y: float) -> np.ndarray:
        # The table point seen straight along +z at projector-frame (x, y): z = D − y·tan(tilt).
        return np.array([x, y, TABLE_DISTANCE_MM - y * np.tan(tilt)])

    def box_frame(yaw_deg: float) -> np.ndarray:
        ex = np.array([1.0, 0.0, 0.0])
        ey = np.cross(up, ex)
        base = np.column_stack([ex, ey / np.linalg.norm(ey), up])
        c, s = np.cos(np.deg2rad(yaw_deg)), np.sin(np.deg2rad(yaw_deg))
        return base @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    return Scene(
        objects=[
            Plane(on_table(0, 0), up, albedo=0.7),
            Box(on_table(-70, 60) + up * 30, (90, 70, 60), box_frame(25), albedo=0.85),
            Box(on_table(80, -80) + up * 17.5, (60, 60, 35), box_frame(-15), albedo=0.6),
            Cylinder(on_table(60, 70), up, radius_mm=32, height_mm=80, albedo=0.8),
            Cone(on_table(-80, -70), up, radius_mm=40, height_mm=75, albedo=0.75),
            Sphere(on_table(15, -15) + up * 38, radius_mm=38, albedo=0.9),
        ]
    )


# --------------------------------------------------------------------------------------------------------
# the paper's configurations (Valiente, Rodas & Andreu, section 5)
# --------------------------------------------------------------------------------------------------------

PAPER_TABLE_MM = 3000.0  # projector centre to the worktable top
PAPER_SCENE_HALF_MM = 1000.0  # the 2 × 2 m scenario
PAPER_CAMERAS = {
    # name: (displacement mm, rotation deg about x, y, z), as printed in the paper
    "paper-parallel": ((300.0, 700.0, 10.0), (0.0, 0.0, 0.0)),
    "paper-orthogonal": ((1400.0, 1400.0, 1400.0), (60.0, 60.0, 0.0)),
    "paper-intermediate": ((700.0, 1400.0, 100.0), (40.0, -10.0, 0.0)),
}


def paper_camera_intrinsics() -> Intrinsics:
    """758×570 pixels, 20 mm lens on a 1/2" sensor (6.4 × 4.8 mm): fx = 20·758/6.4, fy = 20·570/4.8."""
    return Intrinsics(758, 570, np.array([[20 * 758 / 6.4, 0.0, 378.5], [0.0, 20 * 570 / 4.8, 284.5], [0.0, 0.0, 1.0]]))


PAPER_PROJECTOR_F_PX = 525.0


def paper_projector_intrinsics() -> Intrinsics:
    """1024×1024 projector whose default 33-line grid covers the whole 2 × 2 m worktable at 3 m.

    The 30°/120° grid (pitch 30 px, 33 lines) is a rectangle turned by 30°; the largest centred upright
    square inside it has a half-side of 2·240/(1 + √3) = 175.7 px, so f = 175.7 px · 3000 mm / 1000 mm
    = 527 px; 525 px leaves a small margin (docs/decisions/0010-paper-presets.md).
    """
    f = PAPER_PROJECTOR_F_PX
    return Intrinsics(1024, 1024, np.array([[f, 0.0, 511.5], [0.0, f, 511.5], [0.0, 0.0, 1.0]]))


def literal_axis_hit(name: str) -> np.ndarray | None:
    """Where the optical axis of the paper's camera `name`, with its rotation taken literally
    (R_proj_cam = Rz·Ry·Rx), meets the worktable plane z = 3000 mm (x, y in mm), or None if it points away."""
    t, euler = PAPER_CAMERAS[name]
    axis = rotation_from_euler_deg(*euler)[:, 2]
    if axis[2] <= 0:
        return None
    s = (PAPER_TABLE_MM - t[2]) / axis[2]
    return (np.asarray(t) + s * axis)[:2]


def paper_pose(name: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """(R_proj_cam, t_proj_cam, literal): the paper's rotation if the camera axis then meets the 2 × 2 m
    scene, else the camera at the paper's displacement aimed at the scene centre (literal = False)."""
    t, euler = PAPER_CAMERAS[name]
    hit = literal_axis_hit(name)
    t = np.asarray(t, np.float64)
    if hit is not None and np.all(np.abs(hit) <= PAPER_SCENE_HALF_MM):
        return rotation_from_euler_deg(*euler), t, True
    return look_at(t, np.array([0.0, 0.0, PAPER_TABLE_MM])), t, False


def paper_scene() -> Scene:
    """A 2 × 2 m worktable (a 40 mm slab whose top is 3 m from the projector) with cubes, cylinders and
    cones standing on it (towards the projector, −z)."""
    top = PAPER_TABLE_MM
    up = np.array([0.0, 0.0, -1.0])

    def yaw(deg: float) -> np.ndarray:
        return rotation_from_euler_deg(0.0, 0.0, deg)

    def cube(x: float, y: float, a: float, deg: float, albedo: float) -> Box:
        return Box((x, y, top - a / 2), (a, a, a), yaw(deg), albedo=albedo)

    return Scene(
        objects=[
            Box((0.0, 0.0, top + 20.0), (2 * PAPER_SCENE_HALF_MM, 2 * PAPER_SCENE_HALF_MM, 40.0), albedo=0.7),
            Cone((0.0, 0.0, top), up, radius_mm=150, height_mm=350, albedo=0.8),
            cube(-330, -200, 250, 20, 0.85),
            Cylinder((300.0, -220.0, top), up, radius_mm=110, height_mm=300, albedo=0.8),
            cube(250, 250, 200, -10, 0.75),
            Cylinder((150.0, 700.0, top), up, radius_mm=120, height_mm=300, albedo=0.8),
            cube(550, 600, 250, -30, 0.85),
            Cone((-300.0, 380.0, top), up, radius_mm=130, height_mm=300, albedo=0.75),
            cube(-650, -650, 300, 15, 0.8),
            Cylinder((-650.0, 650.0, top), up, radius_mm=150, height_mm=350, albedo=0.8),
            Cone((650.0, -600.0, top), up, radius_mm=180, height_mm=400, albedo=0.75),
        ]
    )


def _paper_rig(name: str, truth: ProCam | None) -> SimRig:
    R, t, literal = paper_pose(name)
    procam = truth or ProCam(paper_camera_intrinsics(), paper_projector_intrinsics(), R, t)
    scene = paper_scene()
    (tx, ty, tz), (rx, ry, rz) = PAPER_CAMERAS[name]
    how = "rotation as printed" if literal else "aimed at the scene centre (the printed rotation misses the scene)"
    return SimRig(
        name=name,
        procam=procam,
        scene=scene,
        depth_range_mm=depth_range(procam, scene),
        description=(
            f"the paper's {name.removeprefix('paper-')} configuration: 758x570 camera (20 mm lens, 1/2\") at "
            f"({tx:g}, {ty:g}, {tz:g}) mm, {how}; printed rotation ({rx:g}, {ry:g}, {rz:g}) deg; 2x2 m worktable "
            "3 m from the projector with cubes, cylinders and cones"
        ),
    )


def preset(name: str, *, truth: ProCam | None = None) -> SimRig:
    """The simulated rig called `name` (one of PRESETS). `truth` replaces the preset's calibration (e.g.
    the [sim] truth file of rig.toml); the scene stays. Unknown names raise ConfigError listing PRESETS."""
    if name == "tabletop":
        procam = truth or tabletop_procam()
        scene = tabletop_scene()
        return SimRig(
            name=name,
            procam=procam,
            scene=scene,
            depth_range_mm=depth_range(procam, scene),
            description=(
                "tabletop: 1280x1024 camera 306 mm beside a 1024x1024 projector, converged on a table 850 mm "
                "away (tilted 10 deg) carrying two boxes, a cylinder, a cone and a sphere"
            ),
        )
    if name in PAPER_CAMERAS:
        return _paper_rig(name, truth)
    raise ConfigError(f"unknown simulated scene {name!r}; the presets are: {', '.join(PRESETS)}")
