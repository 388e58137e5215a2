"""What is plugged in: serial ports (for the trigger board) and V4L2 cameras, for `rig devices`.

Serial ports come from pyserial's `serial.tools.list_ports` (USB VID:PID, serial number) with their stable
/dev/serial/by-id names. Cameras come from sysfs (/sys/class/video4linux: name, driver) and /dev/v4l/by-id; each
node is asked VIDIOC_QUERYCAP whether it captures video (a UVC camera has a second, metadata-only node), and its
formats come from `v4l2-ctl --list-formats-ext` when v4l-utils is installed, else from the VIDIOC_ENUM_FMT and
VIDIOC_ENUM_FRAMESIZES ioctls directly (docs/decisions/0031-camera-listing-without-streaming.md). Nothing here
starts a stream or changes a setting, so listing is safe while another program uses the camera.
"""

from __future__ import annotations

import fcntl
import os
import re
import shutil
import struct
import subprocess
from pathlib import Path
from typing import Any

SYS_V4L = Path("/sys/class/video4linux")
DEV = Path("/dev")

# ioctl numbers from linux/videodev2.h (_IOR/_IOWR('V', nr, struct)), stable kernel ABI.
VIDIOC_QUERYCAP = 0x80685600  # _IOR('V', 0, struct v4l2_capability) (104 bytes)
VIDIOC_ENUM_FMT = 0xC0405602  # _IOWR('V', 2, struct v4l2_fmtdesc) (64 bytes)
VIDIOC_ENUM_FRAMESIZES = 0xC02C564A  # _IOWR('V', 74, struct v4l2_frmsizeenum) (44 bytes)
V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_VIDEO_CAPTURE_MPLANE = 0x00001000
V4L2_CAP_DEVICE_CAPS = 0x80000000
V4L2_BUF_TYPE_VIDEO_CAPTURE = 1
V4L2_FRMSIZE_TYPE_DISCRETE = 1


# ----- serial ports -----------------------------------------------------------------------------------------------


def _links(folder: Path) -> dict[str, list[str]]:
    """realpath -> the symlinks in `folder` pointing at it (e.g. /dev/serial/by-id/usb-Arduino…)."""
    out: dict[str, list[str]] = {}
    if not folder.is_dir():
        return out
    for link in sorted(folder.iterdir()):
        try:
            target = os.path.realpath(link)
        except OSError:
            continue
        out.setdefault(target, []).append(str(link))
    return out


def list_serial_ports(*, include_legacy: bool = False, by_id_dir: Path = DEV / "serial" / "by-id") -> list[dict]:
    """Serial ports as dicts: device, by_id (stable path or None), description, vid_pid ("2341:0043" or None),
    serial_number, manufacturer, product, hwid.

    Ports without any hardware information (the legacy /dev/ttyS* placeholders most PCs have) are left out unless
    `include_legacy`. USB ports come first, then by device name.
    """
    from serial.tools import list_ports

    by_id = _links(by_id_dir)
    out = []
    for p in list_ports.comports():
        if not include_legacy and (p.hwid in (None, "", "n/a")) and p.vid is None:
            continue
        ids = by_id.get(os.path.realpath(p.device), [])
        out.append(
            {
                "device": p.device,
                "by_id": ids[0] if ids else None,
                "description": None if p.description in (None, "n/a") else p.description,
                "vid_pid": f"{p.vid:04x}:{p.pid:04x}" if p.vid is not None and p.pid is not None else None,
                "serial_number": p.serial_number,
                "manufacturer": p.manufacturer,
                "product": p.product,
                "hwid": None if p.hwid in (None, "n/a") else p.hwid,
            }
        )
    out.sort(key=lambda d: (d["vid_pid"] is None, d["device"]))
    return out


# ----- cameras ----------------------------------------------------------------------------------------------------


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None


def _cstr(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", errors="replace")


def parse_querycap(buf: bytes) -> dict:
    """struct v4l2_capability -> driver, card, bus_info, capture (bool)."""
    driver, card, bus_info, _version, caps, device_caps = struct.unpack_from("16s32s32sIII", buf)
    effective = device_caps if caps & V4L2_CAP_DEVICE_CAPS else caps
    return {
        "driver": _cstr(driver),
        "card": _cstr(card),
        "bus_info": _cstr(bus_info),
        "capture": bool(effective & (V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_VIDEO_CAPTURE_MPLANE)),
    }


def fourcc_of(code: int) -> str:
    return "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4)).strip()


def _ioctl_formats(fd: int) -> list[dict]:
    """VIDIOC_ENUM_FMT + VIDIOC_ENUM_FRAMESIZES on an open node (sizes only; frame intervals via v4l2-ctl)."""
    formats = []
    for index in range(64):
        buf = bytearray(struct.pack("III32sII12x", index, V4L2_BUF_TYPE_VIDEO_CAPTURE, 0, b"", 0, 0))
        try:
            fcntl.ioctl(fd, VIDIOC_ENUM_FMT, buf)
        except OSError:
            break  # EINVAL: no more formats
        _, _, _, desc, pixfmt, _ = struct.unpack_from("III32sII", buf)
        sizes = []
        for s in range(256):
            fs = bytearray(struct.pack("III24s8x", s, pixfmt, 0, b""))
            try:
                fcntl.ioctl(fd, VIDIOC_ENUM_FRAMESIZES, fs)
            except OSError:
                break
            _, _, kind = struct.unpack_from("III", fs)
            if kind == V4L2_FRMSIZE_TYPE_DISCRETE:
                w, h = struct.unpack_from("II", fs, 12)
                sizes.append({"width": w, "height": h})
            else:  # stepwise / continuous: one entry with the range
                min_w, max_w, _, min_h, max_h, _ = struct.unpack_from("6I", fs, 12)
                sizes.append({"width": f"{min_w}-{max_w}", "height": f"{min_h}-{max_h}"})
                break
        formats.append({"fourcc": fourcc_of(pixfmt), "description": _cstr(desc), "sizes": sizes})
    return formats


_FMT = re.compile(r"^\s*\[\d+\]:\s*'(.{1,4})'\s*\((.*)\)\s*$")
_SIZE_DISCRETE = re.compile(r"^\s*Size:\s*Discrete\s+(\d+)x(\d+)")
_SIZE_RANGE = re.compile(r"^\s*Size:\s*(?:Stepwise|Continuous)\s+(\d+)x(\d+)\s*-\s*(\d+)x(\d+)")
_INTERVAL = re.compile(r"^\s*Interval:.*\(([\d.]+)(?:-[\d.]+)?\s*fps")


def parse_list_formats_ext(text: str) -> list[dict]:
    """`v4l2-ctl --list-formats-ext` output -> [{fourcc, description, sizes: [{width, height, fps: [...]}]}]."""
    formats: list[dict] = []
    for line in text.splitlines():
        if m := _FMT.match(line):
            formats.append({"fourcc": m.group(1).strip(), "description": m.group(2), "sizes": []})
        elif formats and (m := _SIZE_DISCRETE.match(line)):
            formats[-1]["sizes"].append({"width": int(m.group(1)), "height": int(m.group(2)), "fps": []})
        elif formats and (m := _SIZE_RANGE.match(line)):
            formats[-1]["sizes"].append({"width": f"{m.group(1)}-{m.group(3)}", "height": f"{m.group(2)}-{m.group(4)}",
                                         "fps": []})
        elif formats and formats[-1]["sizes"] and (m := _INTERVAL.match(line)):
            formats[-1]["sizes"][-1]["fps"].append(float(m.group(1)))
    return formats


def _v4l2_ctl_formats(device: str) -> list[dict]:
    exe = shutil.which("v4l2-ctl")
    assert exe is not None
    done = subprocess.run([exe, "-d", device, "--list-formats-ext"], capture_output=True, text=True, timeout=5,
                          check=False)
    if done.returncode != 0:
        raise OSError(done.stderr.strip() or f"v4l2-ctl exited with {done.returncode}")
    return parse_list_formats_ext(done.stdout)


def list_cameras(
    *,
    include_non_capture: bool = False,
    probe: bool = True,
    sys_root: Path = SYS_V4L,
    dev_root: Path = DEV,
) -> list[dict]:
    """V4L2 video nodes as dicts: path (the stable /dev/v4l/by-id name when there is one, else /dev/videoN),
    device, by_id, by_path, name, driver, index, capture (True/False, None when the node could not be asked),
    formats ([{fourcc, description, sizes: [{width, height[, fps]}]}]), formats_source, error.

    Nodes that do not capture video (UVC metadata nodes) are left out unless `include_non_capture`; `probe=False`
    skips opening the nodes (no capture flag, no formats). Empty when there is no camera.
    """
    if not sys_root.is_dir():
        return []
    by_id = _links(dev_root / "v4l" / "by-id")
    by_path = _links(dev_root / "v4l" / "by-path")
    out = []
    for entry in sorted(sys_root.iterdir(), key=lambda p: _natural(p.name)):
        if not entry.name.startswith("video"):
            continue
        device = str(dev_root / entry.name)
        real = os.path.realpath(device)
        driver_link = entry / "device" / "driver"
        driver = os.path.basename(os.path.realpath(driver_link)) if os.path.lexists(driver_link) else None
        index = _read(entry / "index")
        ids = by_id.get(real, [])
        cam: dict[str, Any] = {
            "path": ids[0] if ids else device,
            "device": device,
            "by_id": ids,
            "by_path": by_path.get(real, []),
            "name": _read(entry / "name"),
            "driver": driver,
            "index": int(index) if index and index.isdigit() else None,
            "capture": None,
            "formats": [],
            "formats_source": None,
            "error": None,
        }
        if probe:
            _probe(cam)
        if cam["capture"] is False and not include_non_capture:
            continue
        out.append(cam)
    return out


def _probe(cam: dict) -> None:
    device = cam["device"]
    try:
        fd = os.open(device, os.O_RDWR | os.O_NONBLOCK)
    except PermissionError:
        cam["error"] = "permission denied (is your user in the video group?)"
        return
    except OSError as e:
        cam["error"] = e.strerror or str(e)
        return
    try:
        buf = bytearray(104)
        fcntl.ioctl(fd, VIDIOC_QUERYCAP, buf)
        info = parse_querycap(bytes(buf))
        cam["capture"] = info["capture"]
        cam["driver"] = cam["driver"] or info["driver"]
        cam["name"] = cam["name"] or info["card"]
        cam["bus_info"] = info["bus_info"]
        if not info["capture"]:
            return
        if shutil.which("v4l2-ctl"):
            try:
                cam["formats"] = _v4l2_ctl_formats(device)
                cam["formats_source"] = "v4l2-ctl"
                return
            except (OSError, subprocess.SubprocessError) as e:
                cam["error"] = f"v4l2-ctl: {e}"
        cam["formats"] = _ioctl_formats(fd)
        cam["formats_source"] = "ioctl"
    except OSError as e:
        cam["error"] = f"not a V4L2 device ({e.strerror or e})"
    finally:
        os.close(fd)


def _natural(name: str) -> tuple:
    return tuple(int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name))
