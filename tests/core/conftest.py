"""Shared fixtures of the core test suite: the repository's mission files."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.contracts.mission import Mission
from companion.core.feasibility import load_mission

ROOT = Path(__file__).resolve().parents[2]
MISSIONS = ROOT / "mission_files"


@pytest.fixture(scope="session")
def scenario1() -> Mission:
    return load_mission(MISSIONS / "scenario1.toml")


@pytest.fixture(scope="session")
def scenario3() -> Mission:
    return load_mission(MISSIONS / "scenario3.toml")
