"""Progress of a study, counted in runs: a bar on a terminal, plain lines in a log.

A study of hours is usually run in the background (`nohup`, a batch job, CI), where a bar draws
nothing until the end. Off a terminal the progress is therefore a line every `every_s` seconds of
wall time and one at the end: how many runs are done, the time so far and the time left at the
rate so far.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO

from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

LINE_EVERY_S = 60.0


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.1f} min"


class ProgressLines:
    """Progress as plain text lines, written at most every `every_s` seconds.

    `advance` counts a run; a line goes to `stream` when `every_s` seconds passed since the last
    one (by `clock`), and `close` writes the last.
    """

    def __init__(
        self, total: int, label: str, stream: TextIO, every_s: float, clock: Callable[[], float]
    ) -> None:
        self.total, self.label, self.stream, self.every_s, self.clock = total, label, stream, every_s, clock
        self.done = 0
        self.started = self.last = clock()

    def line(self) -> str:
        elapsed = self.clock() - self.started
        text = f"{self.label}: {self.done}/{self.total} runs, {_minutes(elapsed)}"
        if 0 < self.done < self.total:
            text += f", about {_minutes(elapsed / self.done * (self.total - self.done))} left"
        return text

    def advance(self) -> None:
        self.done += 1
        if self.clock() - self.last >= self.every_s:
            self._say()

    def close(self) -> None:
        self._say()

    def _say(self) -> None:
        self.last = self.clock()
        print(self.line(), file=self.stream, flush=True)


@contextmanager
def run_progress(
    total: int,
    label: str,
    enabled: bool = True,
    stream: TextIO | None = None,
    every_s: float = LINE_EVERY_S,
    clock: Callable[[], float] = time.monotonic,
) -> Iterator[Callable[[], None]]:
    """Progress over `total` runs; yields the function that counts one run done.

    On a terminal it is a rich bar (stdout); otherwise `ProgressLines` on `stream` (default
    stderr); nothing if not `enabled`.
    """
    if not enabled:
        yield lambda: None
        return
    if stream is None and sys.stdout.isatty():
        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
        with Progress(*columns, TimeElapsedColumn(), TimeRemainingColumn()) as bar:
            task = bar.add_task(label, total=total)
            yield lambda: bar.advance(task)
        return
    lines = ProgressLines(total, label, stream or sys.stderr, every_s, clock)
    try:
        yield lines.advance
    finally:
        lines.close()
