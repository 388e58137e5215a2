"""benchmarks._readme: the README's blocks are the results files' first tables, filtered as documented."""

from benchmarks._readme import FILTERS, block, first_table, keep_rows

UNSEEN = """# Scenes nobody tuned for

Scenes with points and no warning: 3 of 5.

| seed | rig | objects | pitch px | angles deg | noise | points | coverage % | median % | p99 % | > 1 % share | warning |
|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|
| 100 | tabletop | 4 | 26 | 54/150 | 2.2 | 29984 | 97.4 | 0.0035 | 0.045 | 0.190 |  |
| 101 | converged-1280 | 4 | 16 | 25/99 | 1.3 | no points | 0.0 | – | – | – | ill-posed |
| 102 | converged-1280 | 2 | 20 | 48/154 | 1.4 | 39688 | 84.9 | 0.0124 | 0.131 | 0.058 |  |
| 103 | tabletop | 2 | 26 | 53/138 | 1.6 | 30000 | 90.0 | 0.0124 | 0.131 | 0.300 |  |
| 104 | tabletop | 2 | 26 | 53/138 | 1.6 | 30000 | 90.0 | 0.0124 | 0.131 | 0.250 |  |
"""


def test_the_unseen_block_keeps_the_scenes_with_a_warning_low_coverage_or_a_high_share_only():
    table = keep_rows(first_table(UNSEEN), FILTERS["unseen"])
    assert table[0].startswith("| seed |") and table[1].startswith("|---:|")
    assert [r.split("|")[1].strip() for r in table[2:]] == ["101", "102", "103"]


def test_every_filtered_block_of_the_committed_results_parses():
    for name in FILTERS:
        lines = block(name).splitlines()
        assert len(lines) >= 2 and all(line.startswith("|") for line in lines)
