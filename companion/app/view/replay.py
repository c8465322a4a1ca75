"""A finished run as frames: the output of `uavsearch run` or `uavsearch mc --save-trajectories`.

Reads `mission.toml` (or the mission given), `summary.json` (the seed), `trajectories.csv`
(poses and tasks per step), `steps.csv` (eq. 30, targets found, lambda_2, min distance per step)
and `targets.csv` (each target's cell and the step it was found). The CVT of run r is rebuilt
with `build_world(mission, seed, r)`, as the run built it. For a `uavsearch run` directory the
companions' logs (`uav{i}.csv`) tell when a UAV fell silent.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

from companion.app.evaluation import CompanionLogs, logged_span
from companion.app.view.frames import Figures, UavPose, frame_json, links
from companion.app.view.scene import Scene, build_scene
from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission
from companion.core.world import World, build_world

NEEDED = ("summary.json", "trajectories.csv", "steps.csv", "targets.csv")


class ReplayError(ValueError):
    """A directory that cannot be replayed: names the file and the reason."""


@dataclass(frozen=True)
class Replay:
    """One run of a replay directory: its scene and its frames (JSON strings)."""

    scene: Scene
    frames: list[str]


def _rows(path: Path, algorithm: str | None, run: int | None) -> tuple[list[dict[str, str]], list[tuple]]:
    """The rows of one run of a CSV, and every (algorithm, run) the file holds.

    The rows of the first run in a CSV that matches `algorithm` and `run` (None: any), and
    every (algorithm, run) the file holds."""
    rows: list[dict[str, str]] = []
    runs: dict[tuple[str, int], None] = {}
    chosen = None
    try:
        with path.open(newline="") as f:
            for row in csv.DictReader(f):
                key = (row["algorithm"], int(row["run"]))
                runs.setdefault(key, None)
                if chosen is None and algorithm in (None, key[0]) and run in (None, key[1]):
                    chosen = key
                if key == chosen:
                    rows.append(row)
    except (OSError, KeyError, ValueError) as exc:
        raise ReplayError(f"{path}: unreadable ({exc})") from None
    return rows, list(runs)


def _mission(directory: Path, mission: Path | None) -> Mission:
    path = mission or directory / "mission.toml"
    if not path.exists():
        raise ReplayError(f"{path}: missing (give the run's mission with --mission)")
    return load_mission(path)


def load_replay(
    directory: Path, mission_file: Path | None = None, algorithm: str | None = None, run: int | None = None
) -> Replay:
    """The frames of one run (default: the first in trajectories.csv) of `directory`."""
    for name in NEEDED:
        if not (directory / name).exists():
            raise ReplayError(
                f"{directory / name}: missing; replay needs the output of `uavsearch run` or "
                "`uavsearch mc --save-trajectories`"
            )
    mission = _mission(directory, mission_file)
    try:
        seed = int(json.loads((directory / "summary.json").read_text())["_meta"]["seed"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ReplayError(f"{directory / 'summary.json'}: no _meta.seed ({exc})") from None
    traj, runs = _rows(directory / "trajectories.csv", algorithm, run)
    if not traj:
        wanted = f"{algorithm or 'any algorithm'} run {'any' if run is None else run}"
        raise ReplayError(f"{directory / 'trajectories.csv'}: no rows for {wanted}")
    algorithm, run = traj[0]["algorithm"], int(traj[0]["run"])
    steps_rows, _ = _rows(directory / "steps.csv", algorithm, run)
    target_rows, _ = _rows(directory / "targets.csv", algorithm, run)
    world = build_world(mission.with_algorithm(algorithm), seed, run)
    n = mission.n_uavs
    try:
        n_steps = 1 + max(int(r["step"]) for r in traj)
        poses = np.zeros((n_steps, n, 3))
        tasks = np.full((n_steps, n), -1, dtype=np.int64)
        for r in traj:
            k, i = int(r["step"]), int(r["uav"])
            poses[k, i] = (float(r["x"]), float(r["y"]), float(r["heading"]))
            tasks[k, i] = int(r["task"])
        figures = {
            int(r["step"]): Figures(
                int(r["found"]), float(r["uncertainty"]), float(r["lambda2"]), float(r["min_distance"])
            )
            for r in steps_rows
        }
        found = {int(r["cell"]): int(r["found_step"]) for r in target_rows}
    except (KeyError, ValueError, IndexError) as exc:
        raise ReplayError(f"{directory}: a malformed row ({exc})") from None
    if set(figures) != set(range(n_steps)):
        raise ReplayError(f"{directory / 'steps.csv'}: not one row per step of {algorithm} run {run}")
    frames = _frames(world, poses, tasks, figures, found, _silent_after(directory, n, n_steps))
    truth = [[c, *np.round(world.grid.centres[c], 3).tolist(), s] for c, s in sorted(found.items())]
    scene = msgspec.structs.replace(
        build_scene(world, "replay", seed),
        targets=len(found),
        run=run,
        runs=[list(key) for key in runs],
        truth=truth,
        steps=n_steps,
    )
    return Replay(scene, frames)


def _silent_after(directory: Path, n: int, n_steps: int) -> list[int]:
    """Per UAV, the last step its companion logged (a run's uav{i}.csv); n_steps for batch runs."""
    logs = CompanionLogs(directory, n)
    logs.poll()
    span = logged_span(logs.logs)
    if not span:
        return [n_steps] * n
    return [max(rows) - span.start if rows else -1 for rows in logs.logs.values()]


def _frames(
    world: World,
    poses: np.ndarray,
    tasks: np.ndarray,
    figures: dict[int, Figures],
    found: dict[int, int],
    last_logged: list[int],
) -> list[str]:
    grid, comm_range = world.grid, world.mission.comms.range
    centres = grid.centres
    found_at: dict[int, list[int]] = {}
    for cell, step in found.items():
        if step >= 0:
            found_at.setdefault(step, []).append(cell)
    frames = []
    for k in range(poses.shape[0]):
        flying = [i for i in range(poses.shape[1]) if k <= last_logged[i]]
        uavs = [
            UavPose(float(x), float(y), float(h), int(tasks[k, i]), i not in flying)
            for i, (x, y, h) in enumerate(poses[k])
        ]
        looks = [c for i in flying for c in grid.fov_cell_list(poses[k, i, :2]).tolist()]
        finds = []
        for cell in sorted(found_at.get(k, [])):
            d = np.hypot(*(poses[k, :, :2] - centres[cell]).T)
            finds.append((cell, int(np.argmin(d))))
        mst, _, _ = links(poses[k, :, :2], comm_range)
        frames.append(frame_json(k, uavs, looks, finds, figures[k], mst))
    return frames
