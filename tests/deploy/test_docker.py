"""docker/: the compose files are valid (`docker compose config`, or Debian's `docker-compose`, when
installed: Docker's engine cannot run here), every command they run exists and accepts its
arguments, and they deploy what docs and README say: outputs on a mounted volume, companions that
start once the simulator is healthy, a router only in the client-mode file."""

from __future__ import annotations

import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest
import yaml

from companion.cli.main import build_parser
from companion.core.feasibility import load_mission

ROOT = Path(__file__).resolve().parents[2]
BASE, CLIENT = ROOT / "docker/compose.yaml", ROOT / "docker/compose.client.yaml"
DEFAULT = re.compile(r"\$\{(\w+):-([^}]*)\}")


def _expand(arg: str) -> str:
    """Compose's ${VAR:-default} with the environment unset."""
    return DEFAULT.sub(lambda m: m.group(2), arg)


def _compose_tool() -> list[str] | None:
    docker = shutil.which("docker")
    if docker and subprocess.run([docker, "compose", "version"], capture_output=True).returncode == 0:
        return [docker, "compose"]
    legacy = shutil.which("docker-compose")
    return [legacy] if legacy else None


def _config(*files: Path) -> dict:
    """The merged compose configuration, as the compose tool resolves it (defaults expanded)."""
    tool = _compose_tool()
    if tool is None:
        pytest.skip(
            "neither `docker compose` nor `docker-compose` is installed (apt-get install docker-compose)"
        )
    argv = [*tool, *(a for f in files for a in ("-f", str(f))), "config"]
    env = {"PATH": "/usr/bin:/bin:/usr/local/bin"}  # no MISSION, OUT, ... from the caller
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    return yaml.safe_load(proc.stdout)


@pytest.mark.parametrize("files", [(BASE,), (BASE, CLIENT)], ids=["peer", "client"])
def test_compose_config_deploys_the_swarm(files: tuple[Path, ...]) -> None:
    services = _config(*files)["services"]
    n = load_mission(ROOT / "mission_files/scenario1.toml").n_uavs
    companions = sorted(s for s in services if s.startswith("companion"))
    assert companions == [f"companion{i}" for i in range(n)]
    assert ("router" in services) == (CLIENT in files), "a router only where the mission asks for one"
    for name, s in services.items():
        assert any(str(v).endswith(":/out:rw") or str(v).endswith(":/out") for v in s.get("volumes", [])) or (
            name == "router"
        ), f"{name}: no outputs volume at /out"
        argv = [str(a) for a in s["command"]]
        args = build_parser().parse_args(argv)  # exits (SystemExit) on an unknown command or argument
        assert callable(args.func)
        load_mission(ROOT / args.mission)
    sim = services["sim"]
    assert "healthcheck" in sim and "/out/truth.json" in " ".join(sim["healthcheck"]["test"])
    assert "/out/truth.json" in sim["command"] and "/out/approach.csv" in sim["command"]
    for name in companions:
        s = services[name]
        assert s["depends_on"]["sim"]["condition"] == "service_healthy", name
        assert s["command"][s["command"].index("--out") + 1] == "/out", name
        assert "--steps" in s["command"], f"{name}: a companion ends its mission by itself"
        if CLIENT in files:
            assert s["depends_on"]["router"]["condition"] == "service_healthy", name
    if CLIENT in files:
        assert "healthcheck" in services["router"]


@pytest.mark.parametrize("path", [BASE, CLIENT], ids=["peer", "client"])
def test_compose_commands_parse(path: Path) -> None:
    """The same without the compose tool: each command, defaults expanded, is one the CLI accepts."""
    for name, service in yaml.safe_load(path.read_text())["services"].items():
        if "command" not in service:
            continue
        args = build_parser().parse_args([_expand(a) for a in service["command"]])
        assert callable(args.func), name
        load_mission(ROOT / args.mission)


def test_dockerfile_entrypoint_is_the_project_cli() -> None:
    text = (ROOT / "docker/Dockerfile").read_text()
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert 'ENTRYPOINT ["uavsearch"]' in text and "uavsearch" in scripts
    for src in re.findall(r"^COPY (\S+)", text, flags=re.M):
        assert (ROOT / src).exists(), src
