"""The default shirt dressed on the default body and simulated through a short walk (real solver,
real body, the 12 mm training level), once per test session: the simulation tests check it and the
dataset tests render it."""

import pytest

from factory.simulate import SimulationConfig, simulate

SHIRT_FRAMES = 6


@pytest.fixture(scope="session")
def shirt_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("shirt_walk")
    config = SimulationConfig(garment="shirt", motion="walk", frames=SHIRT_FRAMES)
    return config, out, simulate(config, out, progress=False)
