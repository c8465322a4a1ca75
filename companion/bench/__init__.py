"""Benchmarks of the companion process (the batch engine's `uavsearch bench` is in batch.experiments)."""
