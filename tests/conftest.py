"""Shared fixtures: small real pattern specs and tables (generated, never mocked)."""

import importlib.util
from pathlib import Path

import pytest

from assets.pattern import MarkerTable, PatternSpec, generate_codebook


@pytest.fixture(scope="session")
def default_codebook():
    """The default 4096-ID codebook (about 2 s to generate)."""
    return generate_codebook(PatternSpec())


@pytest.fixture(scope="session")
def small_table(default_codebook):
    """A 3 x 4 marker fabric with an off-zero origin, so no code path can assume origin (0, 0)."""
    spec = PatternSpec(rows=3, cols=4, origin_xy=(0.1234, -0.0567))
    return MarkerTable.build(spec, default_codebook)


@pytest.fixture(scope="session")
def load_benchmark():
    """load_benchmark(name): the script benchmarks/<name>.py as a module (the benchmarks are scripts,
    not a package), loaded once per session."""
    root = Path(__file__).resolve().parents[1] / "benchmarks"
    loaded = {}

    def load(name: str):
        if name not in loaded:
            spec = importlib.util.spec_from_file_location(f"bench_{name}", root / f"{name}.py")
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            loaded[name] = module
        return loaded[name]

    return load
