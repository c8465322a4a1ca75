"""Every subcommand works on a plain `pip install .`: with the extras' packages (Hypothesis for
`fuzz`, Dask distributed for `cluster-bench` and `--scheduler`) unimportable, every subcommand's
help works, and each command that needs an extra says which, in one line, with no traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MISSION = str(ROOT / "mission_files" / "scenario1.toml")
# a plain install: the extras' top-level packages cannot be imported (sys.modules[name] = None)
PLAIN = """
import contextlib, io, json, sys
for name in ("hypothesis", "distributed", "dask"):
    sys.modules[name] = None
from companion.cli.main import build_parser, main
helped = {}
for command in sorted(build_parser()._subparsers._group_actions[0].choices):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main([command, "--help"])
    helped[command] = out.getvalue().startswith("usage:")
print(json.dumps(helped))
"""
NEEDS = {
    ("fuzz", "--campaign", "mission", "--count", "1"): "pip install 'uavsearch[fuzz]'",
    ("cluster-bench", "--missions", MISSION): "pip install 'uavsearch[cluster]'",
    ("mc", MISSION, "--runs", "1", "--steps", "5", "--out", "mc", "--scheduler", "tcp://127.0.0.1:9"): (
        "pip install 'uavsearch[cluster]'"
    ),
}


def _plain(code: str, *args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def test_every_subcommand_helps_without_the_extras(tmp_path: Path) -> None:
    proc = _plain(PLAIN, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    helped = json.loads(proc.stdout.splitlines()[-1])
    assert len(helped) > 20 and all(helped.values()), helped


def test_a_command_that_needs_an_extra_names_it_in_one_line(tmp_path: Path) -> None:
    run = "import sys\nfor n in ('hypothesis', 'distributed', 'dask'):\n    sys.modules[n] = None\n"
    run += "from companion.cli.main import main\nsys.exit(main(sys.argv[1:]))"
    for argv, extra in NEEDS.items():
        proc = _plain(run, *argv, cwd=tmp_path)
        what = f"uavsearch {' '.join(argv)}"
        assert proc.returncode in (1, 2), (what, proc.returncode, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and extra in lines[0] and "Traceback" not in proc.stderr, (what, proc.stderr)
