"""`uavsearch versus`: two `uavsearch mc` outputs of the same runs compared run by run
(`companion.batch.versus`): the arithmetic on hand-made folders, its refusals, and the command on
a real `mc` output against itself (every change 0)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from companion.batch.versus import compare
from tests.cli import uavsearch

FIELDS = (
    "algorithm",
    "run",
    "seed",
    "steps",
    "mean_target_time",
    "mean_uncertainty",
    "closest_approach",
    "separation_losses",
    "link_losses",
)


def _folder(path: Path, rows: list[tuple]) -> Path:
    path.mkdir()
    with (path / "runs.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(FIELDS)
        w.writerows(rows)
    return path


def test_the_changes_are_paired_means_over_the_common_runs(tmp_path: Path) -> None:
    before = _folder(
        tmp_path / "a",
        [
            ("proposed", 0, 1, 100, 50.0, 0.20, 150.0, 0, 0),
            ("proposed", 1, 1, 100, 60.0, 0.30, 120.0, 0, 0),
            ("proposed", 2, 1, 100, 70.0, 0.40, 130.0, 0, 0),  # not in `after`: left out
            ("no-ta", 0, 1, 100, 80.0, 0.25, 90.0, 1, 0),
        ],
    )
    after = _folder(
        tmp_path / "b",
        [
            ("proposed", 0, 1, 100, 52.0, 0.21, 200.0, 0, 0),
            ("proposed", 1, 1, 100, 66.0, 0.29, 210.0, 0, 1),
            ("no-ta", 0, 1, 100, 70.0, 0.20, 100.0, 0, 0),
        ],
    )
    proposed, no_ta = compare(before, after)
    assert (proposed.algorithm, proposed.runs, no_ta.runs) == ("proposed", 2, 1)
    assert proposed.before["mean_target_time"] == pytest.approx(55.0)
    assert proposed.after["mean_target_time"] == pytest.approx(59.0)
    t = proposed.change["mean_target_time"]
    assert t.estimate == pytest.approx(4.0)  # (+2, +6)
    half = 12.706 * np.std([2.0, 6.0], ddof=1) / np.sqrt(2)  # Student t, 1 degree of freedom
    assert (t.low, t.high) == pytest.approx((4.0 - half, 4.0 + half), rel=1e-3)
    assert proposed.change["mean_uncertainty"].estimate == pytest.approx(0.0)
    assert proposed.closest == (120.0, 200.0) and proposed.events == (0, 1)
    assert no_ta.change["mean_target_time"].estimate == pytest.approx(-10.0) and no_ta.events == (1, 0)


def test_it_refuses_outputs_that_are_not_the_same_runs(tmp_path: Path) -> None:
    a = _folder(tmp_path / "a", [("proposed", 0, 1, 100, 50.0, 0.2, 150.0, 0, 0)])
    b = _folder(tmp_path / "b", [("proposed", 0, 2, 100, 50.0, 0.2, 150.0, 0, 0)])
    c = _folder(tmp_path / "c", [("no-ta", 0, 1, 100, 50.0, 0.2, 150.0, 0, 0)])
    with pytest.raises(ValueError, match="not the same run"):
        compare(a, b)
    with pytest.raises(ValueError, match="share no run"):
        compare(a, c)
    with pytest.raises(ValueError, match=r"no runs\.csv"):
        compare(a, tmp_path)


def test_the_command_on_a_real_output_against_itself(tmp_path: Path) -> None:
    out = tmp_path / "mc"
    run = uavsearch(
        "mc",
        "--mission",
        "mission_files/scenario1.toml",
        "--algorithms",
        "proposed,no-ta",
        "--runs",
        "2",
        "--steps",
        "60",
        "--seed",
        "3",
        "--out",
        str(out),
        "--quiet",
        "--workers",
        "1",
    )
    assert run.returncode == 0, run.stderr
    changes = compare(out, out)
    assert [c.algorithm for c in changes] == ["proposed", "no-ta"]
    assert all(c.runs == 2 and c.change["mean_target_time"].estimate == 0.0 for c in changes)
    shown = uavsearch("versus", str(out), str(out))
    assert shown.returncode == 0, shown.stderr
    assert "proposed" in shown.stdout and "+0.00" in shown.stdout
    bad = uavsearch("versus", str(out), str(tmp_path))
    assert bad.returncode == 2 and "no runs.csv" in bad.stderr
