"""Copy the measured tables from benchmarks/results/ into README.md, between markers.

    .venv/bin/python -m benchmarks._readme        (`make bench` runs it after the benchmarks)

A block `<!-- results:NAME -->` … `<!-- /results -->` in README.md is replaced by the first table of
benchmarks/results/NAME.md (rows filtered as below), so the README never quotes a number that the committed results
files do not hold. Private (leading underscore): benchmarks/run_all.py does not run it as a benchmark.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
README = ROOT / "README.md"


def first_table(text: str) -> list[str]:
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| "))
    end = start
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return lines[start:end]


def keep_rows(table: list[str], predicate) -> list[str]:
    head, rule, rows = table[0], table[1], table[2:]
    return [head, rule, *[r for r in rows if predicate([c.strip() for c in r.strip("|").split("|")])]]


FILTERS = {
    # The fault matrix: the 5 % rows and the all-kinds rows.
    "bench_faults": lambda c: c[1] == "0.05" or c[0] == "all kinds",
    # The paper's experiment: the noisy rows (exact and calibration-error rows are in paper.md).
    "paper": lambda c: c[1] == "noisy",
    # The random scenes: those with a warning, under 85 % coverage or over 0.25 % of points more than 1 % off (all in unseen.md).
    "unseen": lambda c: c[11] != "" or _num(c[7]) < 85.0 or _num(c[10]) > 0.25,
}


def _num(cell: str) -> float:
    """A table cell as a number; NaN for the en dash of a missing value."""
    try:
        return float(cell)
    except ValueError:
        return float("nan")


def block(name: str) -> str:
    text = (RESULTS / f"{name}.md").read_text(encoding="utf-8")
    table = first_table(text)
    if name in FILTERS:
        table = keep_rows(table, FILTERS[name])
    return "\n".join(table)


def main() -> int:
    readme = README.read_text(encoding="utf-8")
    pattern = re.compile(r"(<!-- results:([\w-]+) -->\n).*?(<!-- /results -->)", re.S)
    names = []

    def repl(m: re.Match) -> str:
        names.append(m.group(2))
        return f"{m.group(1)}{block(m.group(2))}\n{m.group(3)}"

    out = pattern.sub(repl, readme)
    README.write_text(out, encoding="utf-8")
    print(f"README.md: refreshed {', '.join(names)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
