"""`rig reconstruct IMAGE`: decode one saved camera image into points, a range map and a recording."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    """Add this module's verbs to the app."""
    app.command("reconstruct")(reconstruct_cmd)


def reconstruct_cmd(
    image: Path = typer.Argument(..., help="camera image of the projected grid (PNG, TIFF, … any OpenCV reads; 8 or 16 bit)"),
    config: Path = typer.Option(None, "--config", "-c", help="rig.toml (default: the built-in simulated rig)"),
    out: Path = typer.Option(None, "--out", "-o", help="write a Rerun recording (.rrd) with the image, grid, depth and points"),
    ply: Path = typer.Option(None, "--ply", help="write the points as binary PLY (world = projector frame, mm)"),
    depth: Path = typer.Option(None, "--depth", help="write the camera depth map as float32 .npy (mm, NaN = none)"),
    labeller: str = typer.Option(None, "--labeller", help="epipolar (default) or paper; default from rig.toml"),
    repeat: int = typer.Option(1, "--repeat", min=1, help="run the reconstruction N times (timing)"),
    as_json: bool = typer.Option(False, "--json", help='print {"median_ms": …, "stages": {…}, "points": …} as JSON'),
) -> None:
    """Reconstruct one image with the configured rig's calibration and pattern."""
    import json
    import statistics

    import cv2

    from calibration.errors import ConfigError, ReconstructionError
    from reconstruction.pipeline import reconstruct
    from rig.config import load_config
    from rig.acquire import save_products
    from rig.registry import reconstruct_options, resolve_procam

    cfg = load_config(config)
    if labeller is not None and labeller not in ("epipolar", "paper"):
        raise ConfigError(f"--labeller {labeller!r}: expected 'epipolar' or 'paper'")
    if out is not None and out.suffix != ".rrd":
        raise ConfigError(f"--out {out}: the recording must end in .rrd")
    if not image.is_file():
        raise ReconstructionError(f"{image}: no such image file")
    img = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ReconstructionError(f"{image}: OpenCV cannot read this file as an image (use PNG, TIFF, BMP or JPEG)")
    procam, source = resolve_procam(cfg)
    options = reconstruct_options(cfg, labeller=labeller)
    times, stages = [], []
    result = None
    first_ms = None
    if repeat > 1:
        # one untimed run first: it builds the per-rig tables and loads (or, in a fresh checkout, compiles) the
        # kernels; the figures are per frame at camera rate
        first_ms = reconstruct(img, procam, cfg.pattern, options=options).stats["ms"]["total"]
    for _ in range(repeat):
        result = reconstruct(img, procam, cfg.pattern, options=options)
        times.append(result.stats["ms"]["total"])
        stages.append(result.stats["ms"])
    assert result is not None
    save_products(result, ply=ply, depth=depth)
    if out is not None:
        _write_recording(out, img, procam, cfg.pattern, result)
    if as_json:
        keys = stages[0].keys()
        summary = {
            "median_ms": statistics.median(times),
            "stages": {k: statistics.median(s[k] for s in stages) for k in keys if k != "total"},
            "points": result.n_points,
            "junctions_found": result.stats["junctions_found"],
            "junctions_labelled": result.stats["junctions_labelled"],
            "repeat": repeat,
            "first_run_ms": first_ms,
            "warnings": result.warnings,
        }
        typer.echo(json.dumps(summary))
    else:
        s = result.stats
        typer.echo(
            f"{s['points']} points from {s['junctions_labelled']} of {s['junctions_found']} junctions "
            f"({s['ms']['total']:.1f} ms; labeller {options.labeller}; calibration: {source})"
        )
        for w in result.warnings:
            typer.echo(f"warning: {w}", err=True)
        for what, p in (("recording", out), ("points", ply), ("depth", depth)):
            if p is not None:
                typer.echo(f"{what}: {p}")


def _write_recording(out: Path, img, procam, pattern, result) -> None:
    from rig.log_reconstruction import log_reconstruction
    from rig.recording import open_recording

    pattern_image = pattern.render(procam.projector.width, procam.projector.height)
    with open_recording(out, procam=procam, pattern_image=pattern_image) as rec:
        rec.log_frame(0, img)
        log_reconstruction(rec.stream, result)
