"""Metrics of confirmed detections (issue 37): what an imperfect sensor's runs are scored by.

A target counts when some UAV holds it *confirmed* (`RunResult.confirm_steps`; for a perfect
sensor the first look confirms, so these are the first-sight metrics). Per run: the mean time to a
confirmed detection (a target never confirmed counting as the run's length), the targets never
confirmed and the false confirmations (cells holding no target that some UAV confirmed). Over
time: the swarm's probability of success, POS(k), the fraction of the targets confirmed at or
before sampling moment k; over runs it is the mean (runs with as many targets each: over runs and
targets) with a 95 % band, like the targets-found curve.
"""

from __future__ import annotations

import numpy as np

from companion.batch.engine import RunResult


def pos_curve(confirm_steps: np.ndarray, steps: int) -> np.ndarray:
    """POS(k) for k = 0 .. steps - 1: the fraction of targets confirmed at step k or before.

    `confirm_steps` holds each target's confirmation step (-1 never); without targets it is 1.
    """
    cs = np.asarray(confirm_steps, dtype=np.int64)
    if cs.size == 0:
        return np.ones(steps)
    confirmed = cs[(cs >= 0) & (cs < steps)]
    return np.cumsum(np.bincount(confirmed, minlength=steps)[:steps]) / cs.size


def run_pos(r: RunResult) -> np.ndarray:
    """A run's POS curve (`pos_curve` of its confirmation steps)."""
    return pos_curve(r.confirm_steps, r.steps)


def confirm_time(r: RunResult) -> float:
    """A run's mean time to a confirmed detection (never confirmed: the run's length; 0 without targets)."""
    return float(r.confirm_times().mean()) if len(r.confirm_steps) else 0.0


def never_confirmed(r: RunResult) -> int:
    """The run's targets that no UAV ever confirmed."""
    return int(np.sum(r.confirm_steps < 0))
