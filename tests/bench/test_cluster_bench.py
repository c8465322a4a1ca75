"""Smoke test of `uavsearch cluster-bench`: a tiny run prints its table and writes its rows.

No timing assertion: the machine may be loaded. Real processes, 127.0.0.1 only.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_tiny_run_prints_and_writes_a_row_per_executor(tmp_path: Path) -> None:
    out_json = tmp_path / "rows.json"
    tiny = [
        "--missions",
        "mission_files/scenario1.toml",
        "--workers",
        "1",
        "--study-runs",
        "2",
        "--steps",
        "30",
    ]
    proc = subprocess.run(
        [sys.executable, "-m", "companion.cli", "cluster-bench", *tiny, "--json", str(out_json)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[0].startswith("executor    workers  runs")
    local, dask = json.loads(out_json.read_text())
    assert (local["executor"], dask["executor"]) == ("local pool", "Dask")
    assert local["runs"] == dask["runs"] == 2 * 3
    assert local["efficiency"] == 1.0 and dask["runs_per_minute"] > 0
    assert dask["worker_cpu_seconds_per_run"] > 0 and dask["scheduler_cpu_ms_per_run"] > 0
    leftovers = subprocess.run(["pgrep", "-f", "uavsearch-cluster-bench-"], capture_output=True, text=True)
    assert leftovers.stdout == "", f"processes left behind: {leftovers.stdout}"
