"""One contract for every Projector: the simulated one, the serial driver on the emulator over a real
pseudo-terminal, and (opt-in) a real board named by RIG_TEST_PORT."""

from __future__ import annotations

import contextlib
import os

import numpy as np
import pytest

from drivers.base import Projector, Shown

SIZE = (64, 48)  # (W, H) of the simulated projector used here


@contextlib.contextmanager
def _sim():
    from drivers.sim import SimProjector, SimWorld, preset
    from calibration.models import Intrinsics, ProCam

    rig = preset("tabletop")
    small = Intrinsics(SIZE[0], SIZE[1], [[100, 0, 31.5], [0, 100, 23.5], [0, 0, 1]])
    world = SimWorld(type(rig)(rig.name, ProCam(rig.procam.camera, small, rig.procam.R_proj_cam, rig.procam.t_proj_cam),
                               rig.scene, rig.depth_range_mm, rig.description))
    with SimProjector(world) as p:
        yield p


@contextlib.contextmanager
def _emulated():
    from drivers.serial import Emulator, SerialProjector, open_transport, serve_on_pty

    with serve_on_pty(Emulator(seed=3)) as port:
        with SerialProjector(open_transport(port), timeout_s=0.3, reopen=lambda: open_transport(port)) as p:
            p.hello()
            yield p


@contextlib.contextmanager
def _hardware():
    port = os.environ.get("RIG_TEST_PORT")
    if not port:
        pytest.skip("set RIG_TEST_PORT to a serial device or URL to run the trigger-board hardware tests")
    from drivers.serial import SerialProjector, open_transport

    with SerialProjector(open_transport(port), reopen=lambda: open_transport(port)) as p:
        p.hello()
        yield p


IMPLEMENTATIONS = {
    "sim": _sim,
    "serial-emulator-pty": _emulated,
    "serial-hardware": pytest.param(_hardware, marks=pytest.mark.hardware),
}


@pytest.fixture(params=list(IMPLEMENTATIONS.values()), ids=list(IMPLEMENTATIONS))
def projector(request):
    with request.param() as p:
        yield p


def _patterns(n: int) -> list[np.ndarray]:
    return [np.full((SIZE[1], SIZE[0]), 40 * (k + 1), np.uint8) for k in range(n)]


def test_is_a_projector(projector):
    assert isinstance(projector, Projector)
    d = projector.describe()
    assert isinstance(d, dict) and d


def test_show_reports_and_projects_the_pattern(projector):
    pats = _patterns(3)
    projector.load(pats)
    assert projector.showing is None, "nothing is projected before the first show"
    for k in (2, 0, 1):
        shown = projector.show(k)
        assert isinstance(shown, Shown) and shown.index == k
        np.testing.assert_array_equal(projector.showing, pats[k])


def test_show_times_increase(projector):
    projector.load(_patterns(2))
    a = projector.show(0)
    b = projector.show(1)
    assert b.host_time_s >= a.host_time_s


def test_out_of_range_pattern_is_an_error(projector):
    from calibration.errors import RigError

    projector.load(_patterns(2))
    with pytest.raises(RigError):
        projector.show(5)


def test_stop_is_safe_and_idempotent(projector):
    projector.load(_patterns(1))
    projector.show(0)
    projector.stop()
    projector.stop()
    assert projector.showing is None
    projector.close()
    projector.close()
