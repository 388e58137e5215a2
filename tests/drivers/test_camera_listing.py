"""Device listing (`rig devices`): v4l2-ctl output and V4L2 structs parsed, a sysfs tree walked, the CLI's words."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import pytest

from drivers.listing import (
    V4L2_CAP_DEVICE_CAPS,
    list_cameras,
    list_serial_ports,
    parse_list_formats_ext,
    parse_querycap,
)

# `v4l2-ctl -d /dev/video0 --list-formats-ext` from a UVC webcam (v4l-utils 1.22), with a stepwise entry added as
# v4l2loopback-style drivers print it.
LIST_FORMATS_EXT = """\
ioctl: VIDIOC_ENUM_FMT
\tType: Video Capture

\t[0]: 'YUYV' (YUYV 4:2:2)
\t\tSize: Discrete 640x480
\t\t\tInterval: Discrete 0.033s (30.000 fps)
\t\t\tInterval: Discrete 0.067s (15.000 fps)
\t\tSize: Discrete 1280x720
\t\t\tInterval: Discrete 0.100s (10.000 fps)
\t[1]: 'MJPG' (Motion-JPEG, compressed)
\t\tSize: Discrete 1920x1080
\t\t\tInterval: Discrete 0.033s (30.000 fps)
\t[2]: 'Y16 ' (16-bit Greyscale)
\t\tSize: Stepwise 16x16 - 2048x1536 with step 1/1
\t\t\tInterval: Stepwise 0.017s - 1.000s with step 0.000s (1.000-60.000 fps)
"""


def test_parse_v4l2_ctl_formats():
    formats = parse_list_formats_ext(LIST_FORMATS_EXT)
    assert [f["fourcc"] for f in formats] == ["YUYV", "MJPG", "Y16"]
    assert formats[0]["description"] == "YUYV 4:2:2"
    assert formats[0]["sizes"] == [
        {"width": 640, "height": 480, "fps": [30.0, 15.0]},
        {"width": 1280, "height": 720, "fps": [10.0]},
    ]
    assert formats[1]["sizes"] == [{"width": 1920, "height": 1080, "fps": [30.0]}]
    assert formats[2]["sizes"] == [{"width": "16-2048", "height": "16-1536", "fps": [1.0]}]
    assert parse_list_formats_ext("") == []


def _querycap(*, caps: int, device_caps: int) -> bytes:
    return struct.pack("16s32s32sIII12x", b"uvcvideo", b"HD Pro Webcam C920", b"usb-0000:00:14.0-1", 0x60000,
                       caps, device_caps)


def test_parse_querycap_tells_capture_nodes_from_metadata_nodes():
    capture = parse_querycap(_querycap(caps=V4L2_CAP_DEVICE_CAPS | 0x04A00001, device_caps=0x04200001))
    meta = parse_querycap(_querycap(caps=V4L2_CAP_DEVICE_CAPS | 0x04A00001, device_caps=0x04A00000))
    old_kernel = parse_querycap(_querycap(caps=0x05000001, device_caps=0))  # no device_caps: use caps
    assert capture == {"driver": "uvcvideo", "card": "HD Pro Webcam C920", "bus_info": "usb-0000:00:14.0-1",
                       "capture": True}
    assert meta["capture"] is False and old_kernel["capture"] is True
    assert len(_querycap(caps=0, device_caps=0)) == 104  # sizeof(struct v4l2_capability)


def _fake_tree(root: Path) -> tuple[Path, Path]:
    """A sysfs + /dev layout for one UVC camera (video0 capture, video1 metadata) under `root`."""
    sys_root, dev_root = root / "sys", root / "dev"
    (root / "drivers" / "uvcvideo").mkdir(parents=True)
    for n, index in ((0, 0), (1, 1), (10, 0)):
        node = sys_root / f"video{n}"
        (node / "device").mkdir(parents=True)
        (node / "name").write_text("HD Pro Webcam C920\n")
        (node / "index").write_text(f"{index}\n")
        os.symlink(root / "drivers" / "uvcvideo", node / "device" / "driver")
        dev_root.mkdir(exist_ok=True)
        (dev_root / f"video{n}").write_bytes(b"")  # a regular file: VIDIOC_QUERYCAP fails on it
    (dev_root / "v4l" / "by-id").mkdir(parents=True)
    (dev_root / "v4l" / "by-path").mkdir(parents=True)
    os.symlink("../../video0", dev_root / "v4l" / "by-id" / "usb-046d_HD_Pro_Webcam_C920_ABC-video-index0")
    os.symlink("../../video1", dev_root / "v4l" / "by-id" / "usb-046d_HD_Pro_Webcam_C920_ABC-video-index1")
    os.symlink("../../video0", dev_root / "v4l" / "by-path" / "pci-0000:00:14.0-usb-0:1:1.0-video-index0")
    return sys_root, dev_root


def test_list_cameras_walks_sysfs_and_by_id_links(tmp_path):
    sys_root, dev_root = _fake_tree(tmp_path)
    cams = list_cameras(probe=False, sys_root=sys_root, dev_root=dev_root)
    assert [c["device"] for c in cams] == [str(dev_root / n) for n in ("video0", "video1", "video10")]  # natural order
    first = cams[0]
    assert first["path"] == str(dev_root / "v4l" / "by-id" / "usb-046d_HD_Pro_Webcam_C920_ABC-video-index0")
    assert first["by_path"] == [str(dev_root / "v4l" / "by-path" / "pci-0000:00:14.0-usb-0:1:1.0-video-index0")]
    assert (first["name"], first["driver"], first["index"]) == ("HD Pro Webcam C920", "uvcvideo", 0)
    assert cams[1]["index"] == 1
    assert cams[2]["path"] == str(dev_root / "video10")  # no by-id link: the node itself


def test_probing_a_node_that_is_not_v4l2_reports_it_instead_of_failing(tmp_path):
    sys_root, dev_root = _fake_tree(tmp_path)
    cams = list_cameras(sys_root=sys_root, dev_root=dev_root)
    assert len(cams) == 3
    assert all(c["capture"] is None and "not a V4L2 device" in c["error"] for c in cams)


def test_no_cameras_on_a_machine_without_video4linux(tmp_path):
    assert list_cameras(sys_root=tmp_path / "absent") == []
    if not Path("/sys/class/video4linux").exists():
        assert list_cameras() == []


def test_serial_ports_have_the_documented_fields(tmp_path):
    ports = list_serial_ports(include_legacy=True)
    keys = {"device", "by_id", "description", "vid_pid", "serial_number", "manufacturer", "product", "hwid"}
    assert all(set(p) == keys for p in ports)
    assert all(p["vid_pid"] is not None or p["hwid"] is not None for p in list_serial_ports())
    if not ports:
        pytest.skip("no serial port on this machine to map a by-id link to")
    link_dir = tmp_path / "by-id"
    link_dir.mkdir()
    os.symlink(ports[0]["device"], link_dir / "usb-Teensyduino_USB_Serial_123-if00")
    again = list_serial_ports(include_legacy=True, by_id_dir=link_dir)
    assert again[0]["by_id"] == str(link_dir / "usb-Teensyduino_USB_Serial_123-if00")


def test_rig_devices_says_plainly_when_nothing_is_plugged_in(capsys, monkeypatch):
    import drivers.listing
    from rig.cli import main

    monkeypatch.setattr(drivers.listing, "list_serial_ports", lambda **kw: [])
    monkeypatch.setattr(drivers.listing, "list_cameras", lambda **kw: [])
    assert main(["devices"]) == 0
    out = capsys.readouterr().out
    assert "no V4L2 cameras found (is the camera plugged in? is your user in the video group?)" in out
    assert "no serial ports found" in out
    assert main(["devices", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"serial_ports": [], "cameras": []}


def test_rig_devices_lists_ports_and_cameras_readably():
    from rig.cli.devices import format_devices

    ports = [{"device": "/dev/ttyACM0", "by_id": "/dev/serial/by-id/usb-Arduino_Uno_8573-if00",
              "description": "Arduino Uno", "vid_pid": "2341:0043", "serial_number": "8573", "manufacturer": "Arduino",
              "product": None, "hwid": "USB VID:PID=2341:0043 SER=8573"}]
    cams = [{"path": "/dev/v4l/by-id/usb-cam-video-index0", "device": "/dev/video0", "name": "C920",
             "driver": "uvcvideo", "capture": True, "formats": parse_list_formats_ext(LIST_FORMATS_EXT), "error": None}]
    text = format_devices(ports, cams)
    assert "/dev/ttyACM0  USB 2341:0043  serial 8573  Arduino Uno" in text
    assert 'port = "/dev/serial/by-id/usb-Arduino_Uno_8573-if00"' in text
    assert '/dev/v4l/by-id/usb-cam-video-index0  (/dev/video0)  "C920"  driver uvcvideo' in text
    assert "YUYV (YUYV 4:2:2): 640x480@30,15  1280x720@10" in text
    assert 'device = "/dev/v4l/by-id/usb-cam-video-index0"' in text
    assert "no V4L2 cameras" not in text and "no serial ports" not in text
