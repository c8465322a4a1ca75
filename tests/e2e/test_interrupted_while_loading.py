"""A SIGINT while a process's modules load (a Ctrl-C in its first second, or the launcher stopping
a child it has just started) ends it with exit code 130 and no traceback, as it does once they are
loaded (`companion.contracts.entry`, `sim_vehicles.__main__`).

The process sends the signal to itself from an import hook as numpy starts loading (a
`sitecustomize` on its PYTHONPATH): a real SIGINT at a known point of the start-up, not at a
wall-clock guess."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import pytest

from tests.cli import ROOT
from tests.e2e.conftest import PY, STARTUP_S

MARK = "sitecustomize: SIGINT as numpy loads"
HOOK = f'''
import importlib.abc, os, signal, sys


class InterruptOnNumpy(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "numpy":
            sys.meta_path.remove(self)
            print("{MARK}", file=sys.stderr, flush=True)
            os.kill(os.getpid(), signal.SIGINT)
        return None


sys.meta_path.insert(0, InterruptOnNumpy())
'''
COMMANDS = {
    "uavsearch": [str(Path(PY).with_name("uavsearch")), "run", "{mission}", "--out", "{out}"],
    "python -m companion.cli": [
        PY,
        "-m",
        "companion.cli",
        "companion",
        "--mission",
        "{mission}",
        "--uav",
        "0",
    ],
    "python -m sim_vehicles": [PY, "-m", "sim_vehicles", "--mission", "{mission}"],
}


def _as_in_a_terminal() -> None:
    """SIGINT at its default, as a shell's foreground job has it: a job started in the background
    (`cmd &` in a script, as CI may run) inherits it ignored, and Python then leaves it ignored."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("command", COMMANDS)
def test_a_sigint_while_the_modules_load_ends_quietly(command: str, make_mission, tmp_path: Path) -> None:
    mission = make_mission(n=2)
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(HOOK)
    argv = [a.format(mission=mission.path, out=tmp_path / "out") for a in COMMANDS[command]]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(hook), str(ROOT)])}
    done = subprocess.run(
        argv,
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=STARTUP_S,
        preexec_fn=_as_in_a_terminal,
    )
    assert MARK in done.stderr, "the hook did not fire: " + done.stderr
    assert done.returncode == 130, done.stderr
    assert "Traceback" not in done.stderr + done.stdout, done.stderr
