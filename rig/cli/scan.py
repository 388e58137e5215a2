"""`rig scan`: project the pattern, grab frames, reconstruct, log everything to a Rerun recording."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    app.command("scan")(scan)


def scan(
    out: Path = typer.Option(Path("scan.rrd"), "--out", "-o", help="the Rerun recording to write"),
    config: Path = typer.Option(None, "--config", "-c", help="rig.toml (default: the built-in simulated rig)"),
    frames: int = typer.Option(1, "--frames", "-n", min=1, help="number of scans (grid: one frame each; a moving object)"),
    record: Path = typer.Option(None, "--record", help="also keep the raw frames, manifest and serial transcript here"),
    ply: Path = typer.Option(None, "--ply", help="write the points as binary PLY (world frame, mm)"),
    depth: Path = typer.Option(None, "--depth", help="write the camera depth map as float32 .npy (mm, NaN = none)"),
    pattern: str = typer.Option(
        "grid", "--pattern", help="grid: single shot, moving scenes; graycode: dense, static scenes, 2·(⌈log2 W⌉+⌈log2 H⌉)+2 frames"
    ),
    no_reconstruct: bool = typer.Option(False, "--no-reconstruct", help="capture and record only"),
) -> None:
    """Scan with the configured rig (default: the built-in simulated rig) into a Rerun recording."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from calibration.errors import RigError
    from rig.acquire import ScanRequest, run_scan
    from rig.config import load_config

    _stop_on_sigterm()
    cfg = load_config(config)
    if out.suffix != ".rrd":
        raise typer.BadParameter(f"{out}: the recording must end in .rrd", param_hint="--out")
    request = ScanRequest(
        out=out, frames=frames, record=record, ply=ply, depth=depth, reconstruct=not no_reconstruct, pattern=pattern
    )
    where = cfg.source or "the built-in simulated rig"
    typer.echo(f"scanning {frames} {pattern} scan{'s' if frames > 1 else ''} with {where}", err=True)
    with Progress(
        TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        TextColumn("{task.fields[info]}"), transient=True, disable=frames < 2,
    ) as bar:
        task = bar.add_task("scan", total=frames, info="")

        def on_frame(n: int, info: dict) -> None:
            extra = f"{info['points']} points" if "points" in info else ""
            bar.update(task, advance=1, info=extra)

        try:
            summary = run_scan(cfg, request, on_frame=on_frame)
        except RigError as e:
            kept = getattr(e, "summary", None)
            if kept is not None and kept.frames_captured:
                where_kept = f"{out}" + (f" and {record}" if record else "")
                raise type(e)(f"{e} ({kept.frames_captured} frame(s) captured before the fault are kept in {where_kept})") from e
            raise
    _report(summary, out)
    if summary.interrupted:
        raise typer.Exit(130)


def _stop_on_sigterm() -> None:
    """SIGTERM (a service manager, `kill`) stops the scan like Ctrl-C: frames kept, recording closed."""
    import signal

    def interrupt(signum, frame):  # noqa: ARG001
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:  # started in the background by a shell
        signal.signal(signal.SIGINT, signal.default_int_handler)


def _report(summary, out: Path) -> None:
    s = summary
    state = "interrupted: " if s.interrupted else ""
    typer.echo(
        f"{state}{s.scans_done} of {s.scans_requested} scan(s) done, {s.frames_captured} frame(s) captured; "
        f"calibration: {s.calibration_source}"
    )
    if s.reconstructed:
        typer.echo(f"reconstructed {s.points_total} points")
        if s.capture_waits:
            typer.echo(f"the capture waited {s.capture_waits} time(s), {s.capture_wait_s:.1f} s in all, for the "
                       "reconstruction to make room (it runs beside the capture; decision 0088)")
    else:
        typer.echo("no reconstruction in this recording (frames and rig geometry only)")
    for w in s.warnings[:10]:
        typer.echo(f"warning: {w}", err=True)
    if len(s.warnings) > 10:
        typer.echo(f"warning: … and {len(s.warnings) - 10} more", err=True)
    if s.record:
        typer.echo(f"raw frames, manifest and transcript: {s.record}/")
    typer.echo(f"recording: {out.resolve()}")
    typer.echo(f"open it with: rerun {out}")
