"""`warm.warm_up` compiles every kernel a companion uses: nothing compiles in flight.

A companion warms up with a short loss-free flight of a few agents before it flies; in flight it
also meets unheard and silent peers (disks), message loss and dead UAVs. A kernel compiled for a
new type signature there stalls the companion for seconds, long enough for the autopilot's GCS
failsafe to take the aircraft (seen on a fresh checkout at 10x). Every numba kernel of the core
must already hold the signatures those paths need.
"""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
from numba.core.registry import CPUDispatcher

import companion.core
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.core.warm import warm_up
from companion.core.world import build_world

ROOT = Path(__file__).resolve().parents[2]


def _kernels() -> dict[str, CPUDispatcher]:
    found = {}
    for info in pkgutil.walk_packages(companion.core.__path__, "companion.core."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.__module__ == module.__name__:
                found[f"{module.__name__}.{name}"] = obj
    return found


def _prime_scoring(mission: Mission) -> None:
    """Compile what only the batch engine's scoring reaches (`Scorer`: ground truth, lambda_2, the
    closest approach), which no companion runs, so that the flights show what the agents compile."""
    from companion.batch.engine import Scorer, initial_poses

    poses = initial_poses(mission)
    scorer = Scorer(build_world(mission, 1, 0), np.zeros(1, dtype=np.int64), 1)
    scorer.record(0, poses[:, :2])
    scorer.record_flight(0, poses, np.zeros(len(poses)), np.ones(len(poses), dtype=bool))


def check_in_this_process() -> None:
    """Warm up without the batch engine, then fly what flight meets: raise if any kernel compiled
    a new signature."""
    mission = load_mission(ROOT / "mission_files/scenario1.toml")
    warm_up(mission)
    assert not [m for m in sys.modules if m.startswith("companion.batch")], "warm_up imported batch"
    from companion.batch.engine import simulate

    _prime_scoring(mission)
    kernels = _kernels()
    assert len(kernels) > 10
    before = {name: len(k.signatures) for name, k in kernels.items()}
    lossy = msgspec.structs.replace(mission, comms=msgspec.structs.replace(mission.comms, loss=0.5))
    simulate(lossy, 3, 0, 40)
    simulate(mission, 4, 0, 40, kills={1: 10})
    grown = {name: [str(s) for s in k.signatures[before[name]:]] for name, k in kernels.items()
             if len(k.signatures) > before[name]}  # fmt: skip
    assert not grown, f"compiled in flight: {grown}"


def test_nothing_compiles_after_warm_up_under_loss_silence_and_deaths() -> None:
    """In a fresh process, as a companion starts (other tests may have compiled more here)."""
    code = "from tests.core.test_warm_up import check_in_this_process as c; c()"
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
