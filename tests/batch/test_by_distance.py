"""`uavsearch targets`: per-target paired differences by distance from the start layout."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from companion.batch.by_distance import targets_by_distance
from companion.core.feasibility import load_mission
from companion.core.world import build_grid
from tests.cli import uavsearch

ROOT = Path(__file__).resolve().parents[2]
SCENARIO1 = ROOT / "mission_files" / "scenario1.toml"


def _folder(tmp_path: Path, rows: list[tuple[str, int, int, int]], steps: int = 100) -> Path:
    out = tmp_path / "mc"
    out.mkdir()
    shutil.copyfile(SCENARIO1, out / "mission.toml")
    (out / "summary.json").write_text(json.dumps({"_meta": {"steps": steps}}))
    with (out / "targets.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(("algorithm", "run", "cell", "found_step"))
        w.writerows(rows)
    return out


def _cell_at(distance: float) -> int:
    """The cell whose centre is nearest `distance` m north of scenario 1's start centroid (-20, -980)."""
    grid = build_grid(load_mission(SCENARIO1))
    d = np.hypot(grid.centres[:, 0] + 20.0, grid.centres[:, 1] + 980.0)
    return int(np.argmin(np.abs(d - distance) + np.abs(grid.centres[:, 0] + 20.0)))


def test_bins_pair_each_target_and_take_the_runs_as_the_sample(tmp_path: Path) -> None:
    near, far = _cell_at(300.0), _cell_at(1500.0)
    rows = [
        # run 0: near target 10 vs 20 (-10), far target never seen (100) vs 40 (+60)
        ("proposed", 0, near, 10), ("proposed", 0, far, -1),
        ("no-ta", 0, near, 20), ("no-ta", 0, far, 40),
        # run 1: near 30 vs 26 (+4), near again 8 vs 8 (0)
        ("proposed", 1, near, 30), ("proposed", 1, near, 8),
        ("no-ta", 1, near, 26), ("no-ta", 1, near, 8),
    ]  # fmt: skip
    bins = targets_by_distance(_folder(tmp_path, rows), edges=(0.0, 1000.0, 2000.0))
    assert [(b.low, b.targets) for b in bins] == [(0.0, 3), (1000.0, 1)]
    close, away = bins
    # runs are the sample: run 0's mean -10, run 1's mean (+4 + 0) / 2 = +2
    assert close.difference.n == 2
    assert close.difference.estimate == pytest.approx(-4.0)
    assert close.mean_step == pytest.approx((10 + 30 + 8) / 3)
    assert (close.sooner, close.later) == (1, 1)
    assert away.difference.estimate == pytest.approx(60.0)  # unseen counts as the run's length
    assert (away.sooner, away.later) == (0, 1)


def test_unpaired_runs_and_bad_edges_are_errors(tmp_path: Path) -> None:
    near = _cell_at(300.0)
    out = _folder(tmp_path, [("proposed", 0, near, 10), ("no-ta", 0, near + 1, 12)])
    with pytest.raises(ValueError, match="not paired"):
        targets_by_distance(out)
    with pytest.raises(ValueError, match="increasing"):
        targets_by_distance(out, edges=(500.0, 100.0))


def test_cli_on_a_real_study_with_drawn_starts(tmp_path: Path) -> None:
    out = tmp_path / "study"
    proc = uavsearch(
        "mc", "--mission", str(SCENARIO1), "--algorithms", "proposed,no-ta", "--runs", "3", "--steps", "40",
        "--seed", "2", "--random-starts", "--workers", "1", "--quiet", "--out", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    proc = uavsearch("targets", str(out), "--edges", "0,500,1000,5000")
    assert proc.returncode == 0, proc.stderr
    with (out / "targets_by_distance_proposed_no-ta.csv").open() as f:
        bins = list(csv.DictReader(f))
    with (out / "runs.csv").open() as f:
        runs = [r for r in csv.DictReader(f) if r["algorithm"] == "proposed"]
    assert sum(int(b["targets"]) for b in bins) == sum(int(r["targets"]) for r in runs)
    # the bins' means put back together are each algorithm's mean target time over all targets
    for column, name in (("mean_step", "proposed"), ("baseline_mean_step", "no-ta")):
        total = sum(float(b[column]) * int(b["targets"]) for b in bins) / sum(int(b["targets"]) for b in bins)
        with (out / "targets.csv").open() as f:
            steps = [int(t["found_step"]) for t in csv.DictReader(f) if t["algorithm"] == name]
        assert total == pytest.approx(np.mean([s if s >= 0 else 40 for s in steps]))
    # against itself every difference is 0
    proc = uavsearch("targets", str(out), "--baseline", "proposed")
    assert proc.returncode == 0, proc.stderr
    with (out / "targets_by_distance_proposed_proposed.csv").open() as f:
        for b in csv.DictReader(f):
            assert float(b["difference"]) == 0.0 and b["sooner"] == b["later"] == "0"
    bad = uavsearch("targets", str(tmp_path))
    assert bad.returncode == 2 and "no summary.json" in bad.stderr and "Traceback" not in bad.stderr
