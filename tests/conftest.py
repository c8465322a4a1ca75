"""Hypothesis draws the same examples on every run (profile "ci", the default): a test that passes
here passes in CI, and a counterexample is fixed, not met at random. `HYPOTHESIS_PROFILE=explore`
draws fresh examples (with the example database) to look for new counterexamples."""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
