"""`rig init` and `rig config show`."""

from __future__ import annotations

from pathlib import Path

import typer

config_app = typer.Typer(help="Inspect the configuration.", no_args_is_help=True)


def register(app: typer.Typer) -> None:
    app.command("init")(init)
    app.add_typer(config_app, name="config")


def init(
    path: Path = typer.Argument(Path("rig.toml"), help="where to write the commented configuration"),
    force: bool = typer.Option(False, "--force", help="overwrite an existing file"),
) -> None:
    """Write a commented rig.toml with every key and its default (the built-in simulated rig)."""
    from calibration.errors import ConfigError
    from calibration.file import write_text_atomic
    from rig.config import TEMPLATE

    if path.exists() and not force:
        raise ConfigError(f"{path} exists; pass --force to overwrite it")
    write_text_atomic(path, TEMPLATE)
    typer.echo(f"wrote {path}; edit it, then `rig config show --config {path}`")


@config_app.command("show")
def show(config: Path = typer.Option(None, "--config", "-c", help="rig.toml (default: the built-in simulated rig)")) -> None:
    """Print the effective configuration (defaults filled in, paths resolved)."""
    from rig.config import config_to_toml, load_config

    cfg = load_config(config)
    typer.echo(f"# effective configuration from {cfg.source or 'built-in defaults (simulated rig)'}")
    typer.echo(config_to_toml(cfg), nl=False)
