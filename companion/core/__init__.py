"""The pure core of the search algorithm: no I/O, no clocks, no globals, seeded randomness only.

Importing it stamps numba's disk cache of the package's kernels with their imports
(`kernel_cache`), before any kernel is decorated.
"""

from pathlib import Path

from companion.core.kernel_cache import install

install(Path(__file__).resolve().parents[1], "companion")
