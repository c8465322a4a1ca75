"""The layers hold (pyproject.toml, [tool.importlinter]), and each rule is needed: in a copy of the
package, one forbidden import breaks exactly the contract that names its layer, and the same copy
passes once that one contract is removed."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import tomli_w

ROOT = Path(__file__).resolve().parents[2]
LINT = Path(sys.executable).with_name("lint-imports")

# contract name -> (a module of its layer, an import that layer must not make)
VIOLATIONS = {
    "contracts import no layer": ("companion/contracts/frames.py", "companion.core.geometry"),
    "core imports only contracts": ("companion/core/geometry.py", "companion.node.guidance"),
    "node imports only core and contracts": ("companion/node/refusals.py", "companion.batch.stats"),
    "batch imports only core and contracts": ("companion/batch/stats.py", "companion.node.refusals"),
    "sim_vehicles imports only core and contracts": ("sim_vehicles/clock.py", "companion.node.refusals"),
    "app imports no bench and no command line": ("companion/app/loopback.py", "companion.bench.run_digest"),
    "bench imports no command line": ("companion/bench/run_digest.py", "companion.cli.entry"),
}


def _config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]


def _lint(tree: Path, config: dict) -> subprocess.CompletedProcess[str]:
    (tree / "pyproject.toml").write_text(tomli_w.dumps({"tool": {"importlinter": config}}))
    return subprocess.run(
        [str(LINT), "--no-cache"], cwd=tree, capture_output=True, text=True, timeout=300,
        env={"PYTHONPATH": str(tree), "PATH": "/usr/bin:/bin"},
    )  # fmt: skip


def test_the_tree_keeps_every_contract() -> None:
    """Today's code breaks no layer."""
    result = subprocess.run([str(LINT), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_contract_is_checked() -> None:
    """Each contract of pyproject.toml has a violation below (a new layer gets one too)."""
    assert {c["name"] for c in _config()["contracts"]} == set(VIOLATIONS)


@pytest.mark.parametrize("name", sorted(VIOLATIONS))
def test_each_rule_catches_its_forbidden_import(name: str, tmp_path: Path) -> None:
    """The import breaks the named contract and no other; without that contract it would pass."""
    for package in ("companion", "sim_vehicles"):
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    module, forbidden = VIOLATIONS[name]
    target = tmp_path / module
    target.write_text(target.read_text() + f"\nimport {forbidden}  # noqa: E402\n")
    config = _config()

    broken = _lint(tmp_path, config)
    assert broken.returncode != 0
    assert re.findall(r"^(.+) BROKEN$", broken.stdout, re.M) == [name], broken.stdout

    config["contracts"] = [c for c in config["contracts"] if c["name"] != name]
    assert _lint(tmp_path, config).returncode == 0
