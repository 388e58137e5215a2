"""rig.toml: good files load with paths resolved; each kind of bad file gives one clear line."""

from __future__ import annotations

import tomllib

import pytest

from calibration.errors import ConfigError
from rig.config import TEMPLATE, RigConfig, config_from_dict, config_to_toml, load_config


def test_no_file_is_the_simulated_rig():
    cfg = load_config(None)
    assert cfg == RigConfig()
    assert cfg.camera.device == "sim" and cfg.projector.port == "sim" and cfg.calibration is None
    assert cfg.pattern.alpha1_deg == 30.0 and cfg.pattern.lines == 33


def test_template_is_the_defaults_and_round_trips(tmp_path):
    assert config_from_dict(tomllib.loads(TEMPLATE)) == RigConfig()
    shown = config_to_toml(RigConfig())
    assert config_from_dict(tomllib.loads(shown)) == RigConfig()


def test_paths_are_relative_to_the_file(tmp_path):
    sub = tmp_path / "rigs"
    sub.mkdir()
    (sub / "rig.toml").write_text(
        'calibration = "cal/calibration.json"\n[camera]\ndevice = "replay:captures/one"\n[sim]\ntruth = "truth.json"\n'
        '[projector]\nport = "replay:captures/one/serial.jsonl"\n'
    )
    cfg = load_config(sub / "rig.toml")
    assert cfg.calibration == sub / "cal" / "calibration.json"
    assert cfg.camera.device == f"replay:{sub / 'captures' / 'one'}"
    assert cfg.sim.truth == sub / "truth.json"
    assert cfg.projector.port == f"replay:{sub / 'captures' / 'one' / 'serial.jsonl'}"
    assert cfg.source == (sub / "rig.toml").resolve()


@pytest.mark.parametrize(
    "text, message",
    [
        ("[camra]\ndevice = 'sim'\n", r"camra: unknown key"),
        ("[camera]\nexposure_ms = -1\n", r"camera\.exposure_ms: Input should be greater than 0"),
        ("[camera]\nfourcc = 'MJPEG'\n", r"camera\.fourcc"),
        ("[pattern]\nlines = 1\n", r"pattern\.lines"),
        ("[pattern]\nalpha1_deg = 30\nalpha2_deg = 210\n", r"parallel families"),
        ("[pattern]\nalpha1_deg = 90\n", r"alpha1_deg = 90.*vertical"),
        ("[pattern]\nspacing = 'random'\n", r"pattern\.spacing"),
        ("[reconstruction]\ndepth_min_mm = 500\ndepth_max_mm = 400\n", r"depth_max_mm \(400.0\) must exceed"),
        ("[sim]\nbit_depth = 12\n", r"sim\.bit_depth"),
        ("[camera\n", r"not valid TOML"),
    ],
)
def test_bad_files(tmp_path, text, message):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as info:
        load_config(path)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value).strip()


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="no such configuration file.*rig init"):
        load_config(tmp_path / "nope.toml")


def test_config_is_frozen():
    cfg = RigConfig()
    with pytest.raises(Exception):
        cfg.camera.fps = 10  # type: ignore[misc]


def test_rig_init_and_config_show(tmp_path, capsys):
    from rig.cli import main

    path = tmp_path / "rig.toml"
    assert main(["init", str(path)]) == 0
    assert load_config(path) == RigConfig(source=path.resolve())
    assert main(["init", str(path)]) == 2, "an existing file is not overwritten without --force"
    assert "pass --force" in capsys.readouterr().err
    capsys.readouterr()
    assert main(["config", "show", "--config", str(path)]) == 0
    shown = capsys.readouterr().out
    assert f"from {path.resolve()}" in shown
    assert config_from_dict(tomllib.loads(shown.split("\n", 1)[1])) == RigConfig()


def test_max_sample_error_reaches_the_reconstruction_options(tmp_path):
    """Decision 0131's precision limit: rig.toml's value reaches SheetPrecisionOptions; zero or below is refused."""
    from rig.registry import reconstruct_options

    assert reconstruct_options(RigConfig()).sheet_precision.max_error_pct == 0.5
    cfg = config_from_dict(tomllib.loads("[reconstruction]\nmax_sample_error_pct = 2.0\n"))
    assert reconstruct_options(cfg).sheet_precision.max_error_pct == 2.0
    assert reconstruct_options(cfg).sheet_precision.enabled
    with pytest.raises(ConfigError, match="max_sample_error_pct"):
        config_from_dict(tomllib.loads("[reconstruction]\nmax_sample_error_pct = 0\n"))
