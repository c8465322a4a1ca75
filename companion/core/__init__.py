"""The pure core of the search algorithm: no I/O, no clocks, no globals, seeded randomness only."""
