"""Shared test helpers: paths to fixtures and to the external captures in ../shared/data."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
SHARED_DATA = ROOT.parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    """../shared/data, or skip with the reason when this clone has no ../shared beside it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real captures not found at {SHARED_DATA} (clone the project beside ../shared to run this)")
    return SHARED_DATA


class RrdTools:
    """Read a .rrd back with Rerun's own reader and verify it with the `rerun` CLI."""

    @staticmethod
    def entities(path: Path) -> dict[str, list[str]]:
        """Entity path -> the store summary lines of its chunks (rows, timelines, columns)."""
        from rerun.chunk import RrdReader

        out: dict[str, list[str]] = {}
        for line in RrdReader(str(path)).store().summary().splitlines():
            entity, rest = line.split(" ", 1)
            out.setdefault(entity, []).append(rest)
        return out

    @classmethod
    def rows(cls, path: Path, entity: str) -> int:
        """Total number of rows logged at `entity` (summed over its chunks)."""
        import re

        return sum(int(re.search(r"rows=(\d+)", line).group(1)) for line in cls.entities(path).get(entity, []))

    @staticmethod
    def column(path: Path, entity: str, name: str) -> list:
        """Every value of component column `name` logged at `entity`, in file order."""
        from rerun.chunk import RrdReader

        values: list = []
        for chunk in RrdReader(str(path)).stream():
            if chunk.entity_path != entity:
                continue
            rb = chunk.to_record_batch()
            if name in rb.schema.names:
                values.extend(rb.column(name).to_pylist())
        return values

    @staticmethod
    def verify(path: Path) -> None:
        """`rerun rrd verify` must pass (footer written, chunks decodable)."""
        import shutil
        import subprocess
        import sys

        exe = Path(sys.executable).with_name("rerun")
        cmd = str(exe) if exe.exists() else shutil.which("rerun")
        assert cmd, "the rerun CLI ships with rerun-sdk"
        res = subprocess.run(
            [cmd, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120,
            env={"HOME": str(Path(path).parent), "PATH": "/usr/bin:/bin"},
        )
        assert res.returncode == 0, res.stderr + res.stdout


@pytest.fixture
def rrd() -> RrdTools:
    return RrdTools()
