"""`uavsearch bench --against CHECKOUT`: the CPU seconds of each scenario and algorithm's run in
another checkout and in this one, interleaved, with their ratio (docs/performance.md). Timing is
printed, never asserted: the checks are that both checkouts ran every cell and that the figures
add up."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.cli import ROOT, uavsearch


@pytest.mark.parametrize("how", ["interleaved", "concurrent"])
def test_bench_against_times_every_cell_of_both_checkouts(how: str) -> None:
    concurrent = ("--concurrent",) if how == "concurrent" else ()
    proc = uavsearch("bench", "--against", str(ROOT), "--rounds", "1", "--steps", "30", *concurrent)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == f"CPU seconds per run, minimum of 1 {how} rounds"
    cells = [line.split() for line in lines[2:11]]
    assert [c[0] + " " + c[1] for c in cells] == [
        f"s{s} {a}" for s in (1, 2, 3) for a in ("proposed", "no-ta", "pheromone")
    ]
    old = [float(c[2]) for c in cells]
    new = [float(c[3]) for c in cells]
    assert all(t > 0 for t in old + new)
    total = lines[11].split()
    assert total[0] == "total"
    old_total, new_total, ratio = float(total[1]), float(total[2]), float(total[3].rstrip("x"))
    assert old_total == pytest.approx(sum(old), abs=0.005)
    assert new_total == pytest.approx(sum(new), abs=0.005)
    # The printed totals are rounded to 0.0005 s and the ratio to 0.005: the ratio of the unrounded
    # totals lies within what those roundings allow (with 30 steps a total is a tenth of a second).
    low = (old_total - 0.0005) / (new_total + 0.0005) - 0.005
    high = (old_total + 0.0005) / (new_total - 0.0005) + 0.005
    assert low <= ratio <= high


def test_bench_against_a_directory_that_is_not_a_checkout_says_so(tmp_path: Path) -> None:
    proc = uavsearch("bench", "--against", str(tmp_path), "--rounds", "1", "--steps", "10")
    assert proc.returncode == 2
    assert f"--against {tmp_path}: not a checkout" in proc.stderr


def test_bench_against_with_a_sensor_flies_it_in_both_checkouts() -> None:
    proc = uavsearch(
        "bench", "--against", str(ROOT), "--rounds", "1", "--steps", "20", "--sensor", "0.7,0.05"
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "CPU seconds per run, minimum of 1 interleaved rounds, sensor Pd 0.7, Pf 0.05"
    assert len(lines) == 12 and lines[11].startswith("total")


def test_bench_against_refuses_mission_files_it_would_not_fly() -> None:
    proc = uavsearch("bench", "--against", str(ROOT), "--missions", "mission_files/scenario1.toml")
    assert proc.returncode != 0
    assert "--missions with --against" in proc.stderr
