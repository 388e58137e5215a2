"""`rig view FILE.rrd`: open a scan recording in the Rerun viewer, or say how on a machine without a screen."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    """Add this module's verbs to the app."""
    app.command("view")(view)


def view(
    recording: Path = typer.Argument(..., help="a scan recording (.rrd) written by `rig scan`"),
) -> None:
    """Open a scan recording in the Rerun viewer (on a headless machine: print the commands that would)."""
    import os
    import subprocess
    import sys

    from calibration.errors import ConfigError

    check_recording_path(recording)
    if not has_display(os.environ, sys.platform):
        typer.echo(headless_hint(recording))
        return
    exe = rerun_executable()
    # The viewer runs in the foreground: `rig view` returns when its window is closed, with its exit code.
    try:
        code = subprocess.call([str(exe), str(recording)])
    except OSError as e:
        raise ConfigError(f"cannot start the Rerun viewer {exe}: {e}") from e
    if code != 0:
        raise typer.Exit(code)


def check_recording_path(path: Path) -> None:
    """Raise ConfigError (one line, with the fix) unless `path` is an existing .rrd file."""
    from calibration.errors import ConfigError

    if path.suffix != ".rrd":
        raise ConfigError(f"{path}: not a Rerun recording (expected a .rrd file, as written by `rig scan --out scan.rrd`)")
    if not path.exists():
        partial = path.with_name(path.name + ".partial")
        extra = f"; {partial} exists: that scan was killed before it closed its recording" if partial.exists() else ""
        raise ConfigError(f"{path}: no such recording{extra} (make one with `rig scan --out {path}`)")
    if not path.is_file():
        raise ConfigError(f"{path}: is not a file (expected a .rrd recording)")


def has_display(environ, platform: str) -> bool:
    """True where a viewer window can open: macOS and Windows always; elsewhere only with DISPLAY or WAYLAND_DISPLAY."""
    if platform.startswith(("darwin", "win")):
        return True
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def headless_hint(recording: Path) -> str:
    """One line: the command to run on a machine with a screen, and the headless screenshot form for this one."""
    import shlex

    q = shlex.quote(str(recording))
    shot = shlex.quote(str(recording.with_suffix(".png")))
    return (
        f"no display here (DISPLAY and WAYLAND_DISPLAY unset): on a machine with a screen run `rerun {q}`; "
        f"for a screenshot here: `rerun --headless --window-size 1280x800 --screenshot-to {shot} {q}` "
        "(needs a Vulkan driver, e.g. Debian's mesa-vulkan-drivers)"
    )


def rerun_executable() -> Path:
    """The `rerun` executable installed with rerun-sdk beside this Python, else the one on PATH."""
    import shutil
    import sys

    from calibration.errors import ConfigError

    here = Path(sys.executable).parent
    for name in ("rerun", "rerun.exe"):
        if (here / name).is_file():
            return here / name
    found = shutil.which("rerun")
    if found:
        return Path(found)
    raise ConfigError(
        f"the Rerun viewer (`rerun`) is neither beside {sys.executable} nor on PATH; install it with "
        "`pip install rerun-sdk==0.41.*` in this environment"
    )
