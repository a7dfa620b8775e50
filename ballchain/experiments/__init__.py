"""The paper's experiments in simulation, each a ``run(...)`` returning plain data."""
