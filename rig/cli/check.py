"""`rig check`: handshake with the projector, fire one trigger, grab one frame, say plainly what is wrong."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    app.command("check")(check)


def check(config: Path = typer.Option(None, "--config", "-c", help="rig.toml (default: the built-in simulated rig)")) -> None:
    """Check the rig end to end: projector handshake, one trigger, one frame, calibration and placement."""
    from dataclasses import replace

    from calibration.errors import ConfigError
    from rig.acquire import grab_verified
    from rig.config import load_config
    from reconstruction.labelling import LabelOptions
    from reconstruction.pipeline import judged_margin
    from reconstruction.placement import labelling_margin
    from rig.registry import epipolar_floor_px, open_rig, working_volume

    cfg = load_config(config)
    with open_rig(cfg) as rig:
        p = rig.projector.describe()
        typer.echo("projector: " + ", ".join(f"{k}={v}" for k, v in p.items()))
        c = rig.camera.describe()
        typer.echo("camera:    " + ", ".join(f"{k}={v}" for k, v in c.items()))
        procam = rig.procam
        problem = cfg.pattern.fits(procam.projector.width, procam.projector.height)
        if problem:
            raise ConfigError(f"[pattern]: {problem}")
        rig.projector.load([cfg.pattern.render(procam.projector.width, procam.projector.height)])
        shown = rig.projector.show(0)
        frame = grab_verified(
            rig.camera, shown, settle_s=cfg.camera.settle_ms / 1000.0, timeout_s=cfg.camera.timeout_ms / 1000.0
        )
        img = frame.image
        typer.echo(
            f"trigger:   pattern {shown.index} shown; frame {img.shape[1]}x{img.shape[0]} {img.dtype} "
            f"{frame.timestamp_s - shown.host_time_s:.3f} s after the switch, brightest {int(img.max())}"
        )
        typer.echo(f"calibration: {rig.calibration_source}; baseline {procam.baseline_mm:.1f} mm")
        rig.projector.stop()
    volume = working_volume(cfg)
    floor = epipolar_floor_px(cfg)
    # "ill-posed" below the runner-up miss the labeller needs with this floor (decision 0130)
    margin = judged_margin(labelling_margin(procam, cfg.pattern, depth_range_mm=volume), replace(LabelOptions(), noise_floor_px=floor))
    typer.echo(f"placement: working volume {volume[0]:.0f}–{volume[1]:.0f} mm; {margin.advice()}")
    typer.echo(
        f"labelling: a label offset wins only where the runner-up misses its epipolar lines by more than "
        f"{1.5 * floor:.2f} projector px RMS (epipolar floor {floor:.2f} px, decision 0110)"
    )
    if margin.verdict == "ill-posed":
        typer.echo("rig check: devices OK, but this camera placement cannot label the grid reliably", err=True)
        raise typer.Exit(1)
    typer.echo("rig check: OK")
