"""Scene presets: names, the paper's camera data, the interpretation of its poses, honest depth ranges."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import ConfigError
from calibration.models import rotation_from_euler_deg
from drivers.sim import PRESETS, SimWorld, RenderOptions, preset
from drivers.sim.presets import PAPER_TABLE_MM, literal_axis_hit, paper_pose
from reconstruction.patterns import GridPattern


def test_preset_names_and_unknown_name():
    assert PRESETS == ("tabletop", "paper-parallel", "paper-intermediate", "paper-orthogonal")
    with pytest.raises(ConfigError, match="tabletop, paper-parallel, paper-intermediate, paper-orthogonal"):
        preset("kitchen")


def test_paper_camera_is_the_papers_half_inch_20mm_camera():
    for name in PRESETS[1:]:
        cam = preset(name).procam.camera
        assert (cam.width, cam.height) == (758, 570)
        assert cam.fx == pytest.approx(2368.75) and cam.fy == pytest.approx(2375.0)


def test_paper_poses_keep_the_displacement_and_aim_where_the_printed_rotation_misses():
    R, t, literal = paper_pose("paper-parallel")
    assert literal and np.allclose(R, np.eye(3)) and np.allclose(t, [300, 700, 10])
    hit = literal_axis_hit("paper-intermediate")
    assert hit is not None and hit[1] < -1000  # printed rotation: axis meets the table plane off the 2 m scene
    orth = literal_axis_hit("paper-orthogonal")
    assert orth is None or np.abs(orth).max() > 1000
    for name, disp in (("paper-intermediate", (700, 1400, 100)), ("paper-orthogonal", (1400, 1400, 1400))):
        R, t, literal = paper_pose(name)
        assert not literal and np.allclose(t, disp)
        to_centre = np.array([0, 0, PAPER_TABLE_MM]) - t
        np.testing.assert_allclose(R[:, 2], to_centre / np.linalg.norm(to_centre), atol=1e-12)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    # the printed rotation is what rotation_from_euler_deg reads (sanity of the helper used above)
    assert np.allclose(rotation_from_euler_deg(0, 0, 0), np.eye(3))


def test_paper_grid_covers_the_two_metre_worktable():
    rig = preset("paper-parallel")
    pattern = GridPattern()
    proj = rig.procam.projector
    # table corners seen from the projector: inside the grid's parallelogram of junctions
    corners = np.array([[x, y, PAPER_TABLE_MM] for x in (-1000, 1000) for y in (-1000, 1000)], float)
    q = proj.project(corners) - np.array(pattern.centre_px)
    for family, n in ((1, pattern.n1), (2, pattern.n2)):
        s = (q[:, 1] - n * q[:, 0]) / np.hypot(n, 1)
        lim = pattern.offsets_px(family)[-1] / np.hypot(n, 1)
        assert np.all(np.abs(s) <= lim)


@pytest.mark.parametrize("name", PRESETS)
def test_depth_range_holds_every_lit_surface_the_camera_sees(name):
    rig = preset(name)
    world = SimWorld(rig, options=RenderOptions(supersample=1, noise_grey=0.0))
    truth = world.truth
    assert np.isfinite(truth.depth_cam).mean() > 0.85
    assert truth.lit.mean() > 0.5
    z = truth.depth_cam[truth.lit]
    near, far = rig.depth_range_mm
    assert near <= z.min() and z.max() <= far
    assert far - near < 1.1 * (z.max() - z.min()) + 0.05 * far  # honest: not padded far beyond
    assert len(set(np.unique(truth.object_id[truth.lit])) - {-1}) >= 4  # the grid falls on several objects
