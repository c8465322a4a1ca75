"""In-process batch engine, Monte Carlo runner, experiments and plots."""
