"""Smoke test of `uavsearch companion-bench`: a tiny run prints and returns its figures.

No timing assertion: the machine may be loaded. Real processes, 127.0.0.1 only.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import msgspec
import pytest

from companion.bench.companion_bench import bench_main
from companion.bench.trial_figures import Spread, TrialSummary
from companion.bench.trials import realtime_verdict


def _own_children() -> set[int]:
    """PIDs of this process's live children (none may be left over)."""
    path = Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children")
    return {int(p) for p in path.read_text().split()} if path.exists() else set()


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_quick_run_prints_and_returns_the_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    before = _own_children()
    out_json = tmp_path / "bench.json"
    code = bench_main(["--quick", "--latency-steps", "6", "--sizes", "2,3", "--json", str(out_json)])
    out = capsys.readouterr().out
    assert code == 0
    assert "step latency, observation in -> command out: 4 UAVs" in out
    assert "p99" in out and "all:" in out
    assert "largest real-time swarm in peer mode" in out
    assert "largest real-time swarm in client mode" in out

    report = json.loads(out_json.read_text())
    lat = report["latency"]
    assert lat["n"] == 4 and len(lat["per_uav"]) == 4
    assert all(lat["latency_ms"][q] > 0 for q in ("p50", "p99", "max"))
    assert all(set(u["median_phases"]) == {"inbox", "agent", "publish", "mavlink"} for u in lat["per_uav"])
    assert lat["missing"] == 0  # lockstep: every peer's bundle arrived
    for key in ("peer@0.5", "client@0.5"):
        rt = report["realtime"][key]
        assert rt["trials"], key
        assert rt["largest"] in (0, 2, 3)
        for t in rt["trials"]:
            assert {"pass", "why", "n"} <= set(t)
    assert _own_children() <= before  # every worker and router stopped


def _summary(**figures: object) -> TrialSummary:
    """A 4-UAV trial's summary at T = 2 s that passes, with `figures` replaced."""
    spread = Spread(p50=1.0, p99=2.0, max=3.0)
    ok = TrialSummary(
        n=4,
        mode="peer",
        period_s=2.0,
        steps=10,
        per_uav=[],
        latency_ms=spread,
        lag_ms=Spread(p50=100.0, p99=900.0, max=1000.0),
        overruns=0,
        missing=1,
        expected=100,
        absent_at_start=0,
        stale=0,
        lost=0,
        malformed=0,
        rejected=0,
        received=108,
        swarm_cores=0.5,
        router_cores=0.0,
        machine_busy_cores=1.0,
        viewer=None,
    )
    return msgspec.structs.replace(ok, **figures)


def test_verdict_names_each_failed_condition() -> None:
    assert realtime_verdict(_summary()) == (True, "ok")
    bad = _summary(overruns=2, lag_ms=Spread(p50=100.0, p99=1100.0, max=2100.0), missing=5)
    passed, why = realtime_verdict(bad)
    assert not passed
    assert "2 overruns" in why and "lag p99" in why and "5 late bundles" in why
