"""Shared fixtures: small real pattern specs and tables (generated, never mocked), and the session's
short shirt walk with a tiny capture rendered from it (a real simulation and real renders, made once
per test run and shared by the pytest-xdist workers)."""

import importlib.util
import os
import signal
import sys
from pathlib import Path

import pytest
from filelock import FileLock

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


def _made_once(tmp_path_factory, name: str, make) -> Path:
    """The folder `name` that `make(folder)` fills, made by the first process of this test run that asks
    for it: the xdist workers share one base folder, and the others wait for the first and reuse its
    folder (a session fixture of its own per worker would redo the work on each)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    folder, done = root / name, root / f"{name}.done"
    with FileLock(str(root / f"{name}.lock")):
        if not done.exists():
            folder.mkdir(exist_ok=True)
            make(folder)
            done.touch()
    return folder


#: frames of the session's shirt walk
SHIRT_FRAMES = 6


@pytest.fixture(scope="session")
def shirt_run(tmp_path_factory):
    """The default shirt dressed on the default body and simulated through a short walk (real solver,
    real body, the 12 mm training level): (config, folder, sequence.npz).  Shared: tests copy the folder
    before they simulate into it."""
    from factory.simulate import SimulationConfig, simulate

    config = SimulationConfig(garment="shirt", motion="walk", frames=SHIRT_FRAMES)
    out = _made_once(tmp_path_factory, "shirt_walk", lambda folder: simulate(config, folder, progress=False))
    return config, out, out / "sequence.npz"


@pytest.fixture(scope="session")
def capture_folder(shirt_run, tmp_path_factory):
    """Frames 3 and 4 of the shirt walk from three cameras at 96 x 64 (Workbench): cameras.json,
    images, depth and ground truth per camera, garment.npz, template.npz."""
    from factory.capture import capture
    from factory.plan import RenderSettings

    _, sim, _ = shirt_run
    tiny = RenderSettings(resolution=(96, 64), engine="WORKBENCH", samples=1, denoise=False)
    return _made_once(tmp_path_factory, "capture", lambda folder: capture(
        "shirt", "walk", folder, frames=2, first_frame=3, cameras=3, resolution=(96, 64), render=tiny,
        progress=False, simulation=sim))


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
