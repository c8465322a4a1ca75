"""The fuzzing campaigns' short versions (the long ones: `uavsearch fuzz --campaign all`): every
input is accepted or rejected and counted, nothing crashes, hangs or goes uncounted."""

from __future__ import annotations

import pytest

from companion.app.fuzz import run_campaign

SHORT = {"mesh": 1500, "mavlink": 600, "camera": 600, "mission": 120}


@pytest.mark.parametrize("name", sorted(SHORT))
def test_campaign_short(name: str) -> None:
    c = run_campaign(name, SHORT[name], seed=1)
    assert not c.failures, c.failures[:5]
    assert c.inputs >= SHORT[name]
    assert c.rejected > 0
    if name != "mission":
        assert c.accepted > 0  # the valid inputs among the mutations still get through
