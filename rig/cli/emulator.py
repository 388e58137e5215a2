"""`rig emulator`: the trigger board's firmware emulator on a fresh pseudo-terminal.

Point `[projector] port` (or `rig check`, `rig scan`) at the printed device path: the host talks to it
exactly as to a board on /dev/ttyACM0, faults included.
"""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    app.command("emulator")(emulator)


def emulator(
    faults: str = typer.Option(
        "",
        "--faults",
        help="fault rates 0..1 per frame/request, e.g. drop=0.05,corrupt=0.05 "
        "(kinds: drop corrupt duplicate delay stall reset disconnect; durations: delay_s stall_s disconnect_s)",
    ),
    seed: int = typer.Option(0, "--seed", help="seed of the fault generator (same seed, same faults)"),
    link: str = typer.Option(
        "",
        "--link",
        help="also make this symlink to the terminal, re-pointed after a disconnect fault "
        "(default with disconnect faults: a link in a temporary folder)",
    ),
) -> None:
    """Run the trigger board emulator on a new pseudo-terminal until Ctrl-C or SIGTERM."""
    import os
    import signal
    import tempfile
    import threading

    from drivers.serial import Emulator, EmulatorFaults, serve_on_pty

    spec = EmulatorFaults.parse(faults)
    em = Emulator(faults=spec, seed=seed)
    tmpdir = None
    link_path = link or None
    if link_path is None and spec.disconnect > 0:
        tmpdir = tempfile.TemporaryDirectory(prefix="rig-emulator-")
        link_path = os.path.join(tmpdir.name, "ttyEMU")
    stop = threading.Event()

    def on_term(signum: int, frame: object) -> None:
        stop.set()

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        with serve_on_pty(em, link=link_path) as path:
            active = ", ".join(f"{k}={getattr(spec, k):g}" for k in spec.KINDS if getattr(spec, k) > 0)
            typer.echo(f"emulator listening on {path} (Ctrl-C to stop)")
            if active:
                typer.echo(f"faults: {active}, seed {seed}")
            try:
                while not stop.wait(0.2):
                    pass
            except KeyboardInterrupt:
                pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        if tmpdir is not None:
            tmpdir.cleanup()
    injected = ", ".join(f"{k} {n}" for k, n in em.fault_counts.items() if n)
    typer.echo(
        f"emulator stopped: {len(em.executed)} requests executed, {em.cache_hits} answered from the cache, "
        f"{em.triggers} triggers since the last boot" + (f"; faults injected: {injected}" if injected else "")
    )
