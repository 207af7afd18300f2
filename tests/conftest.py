"""Shared fixtures: small real pattern specs and tables (generated, never mocked)."""

import importlib.util
import signal
import sys
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
            sys.modules[spec.name] = module  # its functions pickle by name (a process pool's tasks)
            spec.loader.exec_module(module)
            loaded[name] = module
        return loaded[name]

    return load


def _sigint_state() -> tuple[object, bool]:
    return signal.getsignal(signal.SIGINT), signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])


#: SIGINT's handler and whether it is blocked, as this process started
SIGINT_AT_START = _sigint_state()


@pytest.fixture(autouse=True)
def _sigint_left_as_found():
    """A test (its fixtures included) that leaves SIGINT ignored, handled otherwise or blocked in this
    process fails: every process started later inherits an ignored or blocked SIGINT, and a job the
    add-on cancels by SIGINT would then not stop."""
    yield
    now = _sigint_state()
    if now != SIGINT_AT_START:
        handler, blocked = SIGINT_AT_START
        signal.signal(signal.SIGINT, handler)
        signal.pthread_sigmask(signal.SIG_BLOCK if blocked else signal.SIG_UNBLOCK, [signal.SIGINT])
        pytest.fail(f"SIGINT is left with handler {now[0]!r}, blocked {now[1]} (at the start: {handler!r}, "
                    f"blocked {blocked})")
