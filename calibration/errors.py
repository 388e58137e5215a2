"""The project's one error hierarchy.

It lives in the lowest layer so that every package (calibration, reconstruction, drivers, rig) can raise
and catch the same classes without an import arrow pointing upwards (docs/decisions/0002-errors-module.md).
Messages say what was expected and what came, and, where there is one, the fix. The CLI maps each class to
an exit code and prints the message as one line, never a traceback.
"""

from __future__ import annotations


class RigError(Exception):
    """Base class of every error this project raises on purpose."""

    exit_code = 1


class ConfigError(RigError):
    """A configuration file (rig.toml) or a command-line option is missing, malformed or inconsistent."""

    exit_code = 2


class CalibrationFileError(ConfigError):
    """A calibration file cannot be read, or does not follow docs/formats.md (names the offending key)."""


class CalibrationError(RigError):
    """Calibration from observations failed: too few views, board not found, degenerate poses, …"""

    exit_code = 3


class DeviceError(RigError):
    """A device (projector, trigger board, camera) cannot be opened or misbehaves."""

    exit_code = 4


class DeviceTimeout(DeviceError):
    """A device did not answer within its deadline (after the retries the protocol allows)."""


class ProtocolError(DeviceError):
    """The trigger board answered something the protocol (docs/protocol.md) does not allow."""


class ReconstructionError(RigError):
    """An input to reconstruction is unusable: unreadable image, size mismatch with the calibration, …

    A frame in which no grid is found is *not* an error: it is an empty result with a warning.
    """

    exit_code = 5
