"""`rig devices`: list the serial ports (trigger board) and V4L2 cameras plugged into this machine."""

from __future__ import annotations

import json

import typer

NO_PORTS = "no serial ports found (is the trigger board plugged in? is your user in the dialout group?)"
NO_CAMERAS = "no V4L2 cameras found (is the camera plugged in? is your user in the video group?)"


def register(app: typer.Typer) -> None:
    app.command("devices")(devices)


def devices(
    as_json: bool = typer.Option(False, "--json", help="print one JSON object instead of the readable lists"),
    show_all: bool = typer.Option(
        False, "--all", help="also legacy serial ports without hardware info and video nodes that do not capture"
    ),
) -> None:
    """List serial ports (USB VID:PID, serial number) and V4L2 cameras (by-id path, driver, formats)."""
    from drivers.listing import list_cameras, list_serial_ports

    ports = list_serial_ports(include_legacy=show_all)
    cameras = list_cameras(include_non_capture=show_all)
    if as_json:
        typer.echo(json.dumps({"serial_ports": ports, "cameras": cameras}, indent=2))
        return
    typer.echo(format_devices(ports, cameras))


def _fps(values: list[float]) -> str:
    return ",".join(f"{v:g}" for v in values)


def format_formats(formats: list[dict], *, max_sizes: int = 6) -> list[str]:
    """One line per pixel format: `YUYV (YUYV 4:2:2): 640x480@30,15  1280x720@10 …`."""
    lines = []
    for f in formats:
        sizes = []
        for s in f.get("sizes", [])[:max_sizes]:
            text = f"{s['width']}x{s['height']}"
            if s.get("fps"):
                text += "@" + _fps(s["fps"])
            sizes.append(text)
        more = len(f.get("sizes", [])) - max_sizes
        if more > 0:
            sizes.append(f"(+{more} more)")
        desc = f" ({f['description']})" if f.get("description") else ""
        lines.append(f"{f['fourcc']}{desc}: " + ("  ".join(sizes) if sizes else "sizes not reported"))
    return lines


def format_devices(ports: list[dict], cameras: list[dict]) -> str:
    """The readable listing `rig devices` prints."""
    out: list[str] = []
    if ports:
        out.append(f"Serial ports ({len(ports)}):")
        for p in ports:
            bits = [p["device"]]
            if p.get("vid_pid"):
                bits.append(f"USB {p['vid_pid']}")
            if p.get("serial_number"):
                bits.append(f"serial {p['serial_number']}")
            label = p.get("product") or p.get("description")
            if p.get("manufacturer") and label and p["manufacturer"] not in label:
                label = f"{p['manufacturer']} {label}"
            if label:
                bits.append(label)
            out.append("  " + "  ".join(bits))
            if p.get("by_id"):
                out.append(f"      port = \"{p['by_id']}\"")
    else:
        out.append(NO_PORTS)
    out.append("")
    if cameras:
        out.append(f"V4L2 cameras ({len(cameras)}):")
        for c in cameras:
            bits = [c["path"]]
            if c["path"] != c["device"]:
                bits.append(f"({c['device']})")
            if c.get("name"):
                bits.append(f"\"{c['name']}\"")
            if c.get("driver"):
                bits.append(f"driver {c['driver']}")
            if c.get("capture") is False:
                bits.append("no video capture (metadata node)")
            out.append("  " + "  ".join(bits))
            for line in format_formats(c.get("formats", [])):
                out.append(f"      {line}")
            if c.get("error"):
                out.append(f"      ({c['error']})")
            if c.get("capture"):
                out.append(f"      device = \"{c['path']}\"")
    else:
        out.append(NO_CAMERAS)
    return "\n".join(out)
