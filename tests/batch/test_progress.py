"""Progress of a study off a terminal (`companion.batch.progress`): plain lines at most every
`every_s` seconds, a last line at the end, the time left at the rate so far; nothing when disabled."""

from __future__ import annotations

import io

from companion.batch.progress import ProgressLines, run_progress


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_lines_come_every_period_with_the_time_left_and_one_at_the_end() -> None:
    clock, out = Clock(), io.StringIO()
    with run_progress(10, "s1: 10 runs", stream=out, every_s=60.0, clock=clock) as advance:
        for _ in range(10):
            clock.now += 25.0  # a run every 25 s: a line at runs 3, 6 and 9 (75 s apart), and the last
            advance()
    lines = out.getvalue().splitlines()
    assert lines[0] == "s1: 10 runs: 3/10 runs, 1.2 min, about 2.9 min left"  # 75 s / 3 runs x 7 left
    assert lines[-1] == "s1: 10 runs: 10/10 runs, 4.2 min"
    assert [int(line.split(": ")[2].split("/")[0]) for line in lines] == [3, 6, 9, 10]


def test_a_short_study_still_says_it_ended() -> None:
    clock, out = Clock(), io.StringIO()
    lines = ProgressLines(2, "tiny", out, 60.0, clock)
    lines.advance()
    lines.advance()
    assert out.getvalue() == ""
    lines.close()
    assert out.getvalue() == "tiny: 2/2 runs, 0.0 min\n"


def test_disabled_progress_writes_nothing() -> None:
    out = io.StringIO()
    with run_progress(3, "quiet", enabled=False, stream=out, every_s=0.0) as advance:
        for _ in range(3):
            advance()
    assert out.getvalue() == ""
