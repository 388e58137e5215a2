"""The `rig` command line: thin verbs that validate inputs, call one library function and report.

Each verb lives in its own module with a `register(app)` function; heavy imports happen inside the
commands so that `rig --help` is instant. Every RigError becomes one readable line and its exit code.
"""

from __future__ import annotations

import sys

import typer

from calibration.errors import RigError

app = typer.Typer(
    name="rig",
    help="Controller for a single-shot structured-light scanning rig (projector + camera + trigger board).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# One module per verb (or group of verbs); each registers itself on `app`.
_MODULES = ["scan", "check", "setup", "simulate", "emulator", "devices", "reconstruct", "calibrate", "view"]


def _register() -> None:
    import importlib

    for name in _MODULES:
        mod = importlib.import_module(f"rig.cli.{name}")
        mod.register(app)


_register()


def main(argv: list[str] | None = None) -> int:
    """Console-script entry point: runs the app, mapping RigError to one line and its exit code."""
    try:
        rv = app(args=argv, standalone_mode=False)
        # Without standalone mode, click returns the code of a typer.Exit instead of raising it.
        if isinstance(rv, int):
            return rv
    except RigError as e:
        typer.echo(f"rig: error: {e}", err=True)
        return e.exit_code
    except KeyboardInterrupt:
        typer.echo("rig: interrupted", err=True)
        return 130
    except typer.Exit as e:
        return e.exit_code
    except typer.Abort:
        typer.echo("rig: aborted", err=True)
        return 130
    except typer.TyperException as e:  # usage errors (typer's own click): show them as click would
        show = getattr(e, "show", None)
        if show is not None:
            show()
        return int(getattr(e, "exit_code", 2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
