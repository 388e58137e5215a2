"""`rig emulator` as a user runs it: a subprocess printing its device path, served until SIGTERM."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from drivers.serial import SerialProjector, open_transport

RIG = Path(sys.executable).with_name("rig")


def test_rig_emulator_serves_a_board_on_a_pty_until_sigterm():
    proc = subprocess.Popen(
        [str(RIG), "emulator", "--faults", "corrupt=0.1", "--seed", "3"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        first = proc.stdout.readline()
        m = re.fullmatch(r"emulator listening on (/dev/pts/\d+) \(Ctrl-C to stop\)\n", first)
        assert m, first
        assert proc.stdout.readline() == "faults: corrupt=0.1, seed 3\n"
        with SerialProjector(open_transport(m.group(1)), timeout_s=0.2) as proj:
            assert proj.hello()["device"] == "rig-trigger-emulator"
            proj.load([np.zeros((2, 2), np.uint8)] * 3)
            for k in range(20):
                assert proj.show(k % 3).index == k % 3
            assert proj.status()["triggers"] == 20
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert re.search(r"emulator stopped: \d+ requests executed, .* 20 triggers since the last boot; faults injected: corrupt \d+", out), out


def test_rig_emulator_rejects_a_bad_fault_spec_with_one_line():
    proc = subprocess.run([str(RIG), "emulator", "--faults", "drop=3"], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert proc.stderr.strip() == "rig: error: fault rate drop=3.0 is outside 0…1"
