"""docker/: every command the compose file runs exists and accepts its arguments."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest
import yaml

from companion.app.cli import build_parser
from companion.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = yaml.safe_load((ROOT / "docker/compose.yaml").read_text())
DEFAULT = re.compile(r"\$\{(\w+):-([^}]*)\}")


def _expand(arg: str) -> str:
    """Compose's ${VAR:-default} with the environment unset."""
    return DEFAULT.sub(lambda m: m.group(2), arg)


@pytest.mark.parametrize("service", sorted(COMPOSE["services"]))
def test_compose_command_parses(service: str) -> None:
    argv = [_expand(a) for a in COMPOSE["services"][service]["command"]]
    args = build_parser().parse_args(argv)  # exits (SystemExit) on an unknown command or argument
    assert callable(args.func)
    mission = getattr(args, "mission", None)
    if mission:
        load_mission(ROOT / mission)


def test_compose_runs_the_whole_swarm() -> None:
    commands = [s["command"][0] for s in COMPOSE["services"].values()]
    assert commands.count("companion") == load_mission(ROOT / "mission_files/scenario1.toml").n_uavs
    assert {"router", "sim"} <= set(commands)


def test_dockerfile_entrypoint_is_the_project_cli() -> None:
    text = (ROOT / "docker/Dockerfile").read_text()
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert 'ENTRYPOINT ["uavsearch"]' in text and "uavsearch" in scripts
    for src in re.findall(r"^COPY (\S+)", text, flags=re.M):
        assert (ROOT / src).exists(), src
