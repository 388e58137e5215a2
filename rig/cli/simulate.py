"""`rig simulate`: render a case on the simulated rig and write it to a folder (frames, truth, rig.toml,
calibration.json) so that it can be reproduced without the simulator."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    """Add this module's verbs to the app."""
    app.command("simulate")(simulate)


def simulate(
    scene: str = typer.Option("tabletop", "--scene", "-s", help="preset: tabletop, paper-parallel, paper-intermediate, paper-orthogonal"),
    out: Path = typer.Option(..., "--out", "-o", help="folder to write (created if missing)"),
    frames: int = typer.Option(1, "--frames", "-n", min=1, help="frames to render (independent noise)"),
    noise_grey: float = typer.Option(1.0, "--noise-grey", min=0.0, help="sensor noise, std dev in 8-bit grey levels"),
    ambient: float = typer.Option(0.05, "--ambient", min=0.0, max=1.0, help="ambient light, fraction of full scale"),
    gamma: float = typer.Option(1.0, "--gamma", min=0.01, help="camera response exponent (grey ∝ radiance^(1/gamma))"),
    bit_depth: int = typer.Option(8, "--bit-depth", help="8 or 16"),
    supersample: int = typer.Option(3, "--supersample", min=1, max=8, help="rays per pixel along each axis"),
    seed: int = typer.Option(0, "--seed", help="noise seed"),
    pattern_pitch: float = typer.Option(None, "--pattern-pitch", help="grid pitch in projector pixels (default 30)"),
    lines: int = typer.Option(None, "--lines", help="lines per family (default 33)"),
    line_width: float = typer.Option(None, "--line-width", help="line width in projector pixels (default 3)"),
    truth: Path = typer.Option(None, "--truth", help="calibration.json to build the rig with instead of the preset's"),
) -> None:
    """Render the grid on a simulated scene; write frames/, truth.npz, calibration.json, rig.toml."""
    import time

    from calibration.errors import ConfigError
    from calibration.file import load_calibration
    from drivers.sim import RenderOptions, preset, write_simulation
    from reconstruction.patterns import GridPattern

    if bit_depth not in (8, 16):
        raise ConfigError(f"--bit-depth must be 8 or 16, got {bit_depth}")
    true_cal = load_calibration(truth).to_procam(source=str(truth)) if truth is not None else None
    rig = preset(scene, truth=true_cal)
    changes = {k: v for k, v in (("pitch_px", pattern_pitch), ("lines", lines), ("line_width_px", line_width)) if v is not None}
    proj = rig.procam.projector
    try:
        pattern = GridPattern(centre_px=((proj.width - 1) / 2, (proj.height - 1) / 2), **changes)
    except ValueError as e:
        raise ConfigError(f"pattern options: {e}") from e
    problem = pattern.fits(proj.width, proj.height)
    if problem:
        raise ConfigError(problem)
    try:
        options = RenderOptions(
            noise_grey=noise_grey, ambient=ambient, gamma=gamma, bit_depth=bit_depth, supersample=supersample
        )
    except ValueError as e:
        raise ConfigError(str(e)) from e
    t0 = time.monotonic()
    folder = write_simulation(out, rig=rig, pattern=pattern, options=options, seed=seed, frames=frames)
    dt = time.monotonic() - t0
    cam = rig.procam.camera
    typer.echo(f"simulated {rig.name}: {rig.description}")
    typer.echo(
        f"wrote {folder}/: frames/000000.png…{frames - 1:06d}.png ({cam.width}x{cam.height}, {bit_depth}-bit), pattern.png, "
        f"truth.npz, calibration.json, rig.toml, simulation.json in {dt:.1f} s"
    )
    typer.echo(f"depth range {rig.depth_range_mm[0]:.0f}–{rig.depth_range_mm[1]:.0f} mm; replay with `--config {folder}/rig.toml`")
