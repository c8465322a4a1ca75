"""The command line as a user reads it: `uavsearch CMD --help` for every subcommand gives every
option a help text with its default (or says it is required, or is a flag); the mission is `FILE`
or `--mission FILE` alike; a mistake prints the subcommand's own usage."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from companion.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
COMMANDS = sorted(build_parser()._subparsers._group_actions[0].choices)  # type: ignore[union-attr]
OPTION = re.compile(r"^  (-\S.*?)(?:\s{2,}(\S.*))?$")


def _help(command: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> str:
    """`uavsearch COMMAND --help`, as printed (the benchmarks' own parsers included)."""
    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    return capsys.readouterr().out


def _options(text: str) -> dict[str, str]:
    """Each option's invocation ('--out OUT') and its help text, from argparse's help output."""
    options: dict[str, str] = {}
    current = None
    for line in text.splitlines():
        match = OPTION.match(line)
        if match:
            current = match.group(1).strip()
            options[current] = match.group(2) or ""
        elif current is not None and line.startswith("   ") and line.strip():
            options[current] += " " + line.strip()
        else:
            current = None
    return options


@pytest.mark.parametrize("command", COMMANDS)
def test_every_option_says_what_it_does_and_its_default(
    command: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    options = _options(_help(command, capsys, monkeypatch))
    assert options, f"uavsearch {command} --help lists no options"
    problems = []
    for invocation, text in options.items():
        if invocation.startswith("-h"):
            continue
        takes_value = bool(re.search(r"^--?[\w-]+ \S", invocation.split(",")[0]))
        if not text.strip():
            problems.append(f"{invocation}: no help text")
        elif takes_value and "default" not in text and "required" not in text:
            problems.append(f"{invocation}: no default in {text!r}")
    assert not problems, f"uavsearch {command} --help: " + "; ".join(problems)


def test_the_mission_is_file_or_dash_dash_mission_in_every_command() -> None:
    parser = build_parser()
    for command in ("run", "mc", "sweep", "companion", "sim", "camera", "keys", "router", "view", "faults"):
        extra = {"companion": ["--uav", "0"], "camera": ["--vehicles", "udpin:127.0.0.1:1"]}.get(command, [])
        by_position = parser.parse_args([command, "m.toml", *extra])
        by_option = parser.parse_args([command, "--mission", "m.toml", *extra])
        assert str(by_position.mission) == str(by_option.mission) == "m.toml", command


def test_a_mistake_prints_the_subcommands_own_usage() -> None:
    for argv, says in (
        (["run", "--mission", "m.toml", "--bogus"], "unrecognized arguments: --bogus"),
        (["run"], "a mission file is required: FILE or --mission FILE"),
        (["mc", "--mission", "a.toml", "b.toml"], "the mission is given twice"),
        (["mc", "m.toml", "--algorithms", "propsed"], "choose from proposed, no-ta, pheromone"),
    ):
        proc = subprocess.run(
            [sys.executable, "-m", "companion.cli", *argv],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=120,
        )
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.startswith(f"usage: uavsearch {argv[0]} "), proc.stderr
        assert says in proc.stderr, proc.stderr
