"""ReplayCamera beyond the contract: which frame list it follows, full bit depth through CAP_IMAGES, runs of
numbered files, the end of a recording, and the errors for broken capture directories."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.errors import DeviceError, DeviceTimeout
from drivers.replay import ReplayCamera, contiguous_runs, load_entries

W, H = 40, 30


def _frame(i: int, dtype=np.uint16, channels: int = 1) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    if dtype == np.uint16:
        img = (xx * 1500 + yy * 10 + i).astype(np.uint16)
    else:
        img = ((xx + yy + i * 7) % 256).astype(np.uint8)
    img[0, 0] = i
    if channels == 3:
        img = np.dstack([img, img // 2, img // 3])
    return img


def _write(folder: Path, name: str, image: np.ndarray) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(folder / name), image)


def _grab_all(cam: ReplayCamera) -> list:
    return [cam.grab(after_s=0.0, timeout_s=1.0) for _ in range(cam.frame_count)]


def test_follows_the_manifest_order_and_carries_its_metadata(tmp_path):
    for i in range(4):
        _write(tmp_path / "frames", f"{i:06d}.png", _frame(i))
    order = [2, 3, 0, 1]
    frames = [{"file": f"frames/{i:06d}.png", "pattern": 10 + i, "timestamp_s": 50.0 + i, "exposure_ms": 8.0}
              for i in order]
    (tmp_path / "manifest.json").write_text(json.dumps({"complete": True, "frames": frames,
                                                        "devices": {"camera": {"kind": "v4l2"}}}))
    with ReplayCamera(tmp_path) as cam:
        got = _grab_all(cam)
        info = cam.describe()
    assert [int(f.image[0, 0]) for f in got] == order
    assert [f.meta["pattern"] for f in got] == [10 + i for i in order]
    assert [f.meta["recorded_timestamp_s"] for f in got] == [50.0 + i for i in order]
    assert got[0].meta["exposure_ms"] == 8.0 and got[0].meta["file"] == "frames/000002.png"
    assert info["frame_list"] == "manifest" and info["frames"] == 4 and info["recorded_camera"] == {"kind": "v4l2"}


def test_a_recording_that_was_never_closed_plays_from_frames_jsonl(tmp_path):
    for i in range(3):
        _write(tmp_path / "frames", f"{i:06d}.png", _frame(i))
    (tmp_path / "manifest.json").write_text(json.dumps({"complete": False, "frames": []}))
    lines = [json.dumps({"file": f"frames/{i:06d}.png", "pattern": 0, "timestamp_s": float(i)}) for i in range(3)]
    # The process died while writing a fourth line: the frames before it are good.
    (tmp_path / "frames.jsonl").write_text("\n".join(lines) + '\n{"file": "frames/0000')
    with ReplayCamera(tmp_path) as cam:
        assert cam.describe()["frame_list"] == "frames.jsonl"
        assert [int(f.image[0, 0]) for f in _grab_all(cam)] == [0, 1, 2]


def test_without_a_manifest_files_play_in_name_order(tmp_path):
    for i in (3, 1, 2):
        _write(tmp_path / "frames", f"img_{i:03d}.png", _frame(i, np.uint8))
    with ReplayCamera(tmp_path) as cam:
        got = _grab_all(cam)
        assert cam.describe()["frame_list"] == "files"
    assert [int(f.image[0, 0]) for f in got] == [1, 2, 3]


def test_sixteen_bit_and_colour_frames_are_read_unchanged(tmp_path):
    grey16 = [_frame(i, np.uint16) for i in range(3)]
    for i, img in enumerate(grey16):
        _write(tmp_path / "a", f"{i:06d}.png", img)
    with ReplayCamera(tmp_path / "a") as cam:
        got = _grab_all(cam)
    assert all(np.array_equal(g.image, w) for g, w in zip(got, grey16))
    assert got[0].image.dtype == np.uint16 and got[0].image.ndim == 2 and int(got[0].image.max()) > 255

    colour = [_frame(i, np.uint8, channels=3) for i in range(2)]
    for i, img in enumerate(colour):
        _write(tmp_path / "b", f"{i:06d}.png", img)
    with ReplayCamera(tmp_path / "b") as cam:
        assert all(np.array_equal(cam.grab(after_s=0.0, timeout_s=1.0).image, w) for w in colour)


def test_gaps_in_the_numbering_start_a_new_run():
    names = ["f/000003.png", "f/000004.png", "f/000005.png", "f/000007.png", "f/x.png", "f/000008.png"]
    assert contiguous_runs([Path(n) for n in names]) == [(0, 3), (3, 1), (4, 1), (5, 1)]
    assert contiguous_runs([Path("f/b_01_000009.png"), Path("f/b_01_000010.png")]) == [(0, 1), (1, 1)]  # 01 != 000009
    assert contiguous_runs([Path("f/0009.png"), Path("f/0010.png"), Path("f/0011.png")]) == [(0, 3)]


def test_a_manifest_with_gaps_and_reordering_plays_every_listed_frame(tmp_path):
    numbers = [3, 4, 5, 9, 10, 1]
    for n in numbers:
        _write(tmp_path / "frames", f"{n:06d}.png", _frame(n))
    _write(tmp_path / "frames", "000006.png", _frame(6))  # on disk but not listed: must not be played
    entries = [{"file": f"frames/{n:06d}.png"} for n in numbers]
    (tmp_path / "manifest.json").write_text(json.dumps({"frames": entries}))
    with ReplayCamera(tmp_path) as cam:
        assert [int(f.image[0, 0]) for f in _grab_all(cam)] == numbers


def test_the_end_of_the_recording_is_an_error_unless_looping(tmp_path):
    for i in range(2):
        _write(tmp_path, f"{i:06d}.png", _frame(i))
    with ReplayCamera(tmp_path) as cam:
        _grab_all(cam)
        with pytest.raises(DeviceError, match=r"has no more frames \(2 played\)"):
            cam.grab(after_s=0.0, timeout_s=1.0)
    with ReplayCamera(tmp_path, loop=True) as cam:
        got = [cam.grab(after_s=0.0, timeout_s=1.0) for _ in range(5)]
    assert [int(f.image[0, 0]) for f in got] == [0, 1, 0, 1, 0]
    assert [f.sequence for f in got] == [1, 2, 3, 4, 5]


def test_grab_waits_for_after_s_and_stamps_host_time(tmp_path):
    _write(tmp_path, "000000.png", _frame(0))
    with ReplayCamera(tmp_path) as cam:
        t0 = time.monotonic()
        frame = cam.grab(after_s=t0 + 0.05, timeout_s=1.0)
        assert frame.timestamp_s > t0 + 0.05 and time.monotonic() >= frame.timestamp_s


def test_an_after_s_beyond_the_deadline_times_out_at_the_deadline(tmp_path):
    _write(tmp_path, "000000.png", _frame(0))
    with ReplayCamera(tmp_path) as cam:
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout):
            cam.grab(after_s=t0 + 5.0, timeout_s=0.1)
        assert 0.09 <= time.monotonic() - t0 < 0.5
        assert cam.played == 0  # the frame is still there for the next grab
        assert int(cam.grab(after_s=0.0, timeout_s=1.0).image[0, 0]) == 0


def test_a_frame_of_another_size_mid_recording_is_an_error(tmp_path):
    _write(tmp_path, "000000.png", _frame(0))
    _write(tmp_path, "000001.png", np.zeros((H + 2, W), np.uint16))
    with ReplayCamera(tmp_path) as cam:
        cam.grab(after_s=0.0, timeout_s=1.0)
        with pytest.raises(DeviceError, match="000001.png is uint16 \\(32, 40\\), but the recording's first frame"):
            cam.grab(after_s=0.0, timeout_s=1.0)


@pytest.mark.parametrize(
    ("setup", "pattern"),
    [
        ("missing", r"no such directory \(record one with `rig scan --record"),
        ("file", "not a directory"),
        ("empty", "no frames .*000000.png"),
        ("bad-json", "cannot read manifest.json"),
        ("missing-frame", "manifest lists frames/000001.png but the file is missing"),
        ("no-file-key", 'frame entry 0 in manifest has no "file"'),
        ("not-an-image", "OpenCV cannot read 000000.png"),
    ],
)
def test_broken_capture_directories_are_named_errors(tmp_path, setup, pattern):
    d = tmp_path / "cap"
    if setup == "file":
        d.write_text("x")
    elif setup == "empty":
        d.mkdir()
        (d / "notes.txt").write_text("no images here")
    elif setup == "bad-json":
        d.mkdir()
        (d / "manifest.json").write_text("{not json")
    elif setup == "missing-frame":
        _write(d / "frames", "000000.png", _frame(0))
        (d / "manifest.json").write_text(json.dumps({"frames": [{"file": "frames/000000.png"},
                                                                 {"file": "frames/000001.png"}]}))
    elif setup == "no-file-key":
        d.mkdir()
        (d / "manifest.json").write_text(json.dumps({"frames": [{"pattern": 0}]}))
    elif setup == "not-an-image":
        d.mkdir()
        (d / "000000.png").write_bytes(b"this is not a PNG")
    with pytest.raises(DeviceError, match=pattern) as err:
        ReplayCamera(d)
    assert str(d) in str(err.value)


def test_replays_what_the_capture_writer_recorded(tmp_path):
    """Record once, replay forever: the lead's CaptureWriter output is this camera's input format."""
    from rig.capture import CaptureWriter

    written = [_frame(i) for i in range(3)]
    with CaptureWriter(tmp_path / "rec", header={"devices": {"camera": {"kind": "sim"}}}) as cw:
        for i, img in enumerate(written):
            cw.write_frame(img, pattern=0, timestamp_s=10.0 + i, exposure_ms=16.7)
    entries, source, _ = load_entries(tmp_path / "rec")
    assert source == "manifest" and len(entries) == 3
    with ReplayCamera(tmp_path / "rec") as cam:
        got = _grab_all(cam)
    assert all(np.array_equal(g.image, w) for g, w in zip(got, written))
    assert [g.meta["recorded_timestamp_s"] for g in got] == [10.0, 11.0, 12.0]
    assert got[0].meta["exposure_ms"] == 16.7
