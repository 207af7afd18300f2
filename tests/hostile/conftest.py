"""The hostile suite: bad, careless and malicious inputs built on the fly, run through the real CLIs
and loaders.  Each test holds one defect that a user or an attacker could meet; the CLIs run as
subprocesses with an address-space limit, so a memory bomb fails the test instead of the machine."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _limit_memory(gib: float):
    def apply():
        limit = int(gib * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    return apply


def run_cli(module: str, *args: object, mem_gib: float = 6.0, timeout: float = 300,
            cwd: Path | None = None) -> subprocess.CompletedProcess:
    """`python -m module args...` under an address-space limit of `mem_gib` (torch and bpy map a few
    GiB of address space on import; what a bomb asks for is far more)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd or ROOT, env=env, preexec_fn=_limit_memory(mem_gib))


def assert_refused(result: subprocess.CompletedProcess, *needles: str) -> str:
    """The run failed with a clear error (no traceback, no crash by signal) whose text holds every
    needle; returns stderr."""
    err = result.stderr
    assert result.returncode > 0, f"accepted (rc {result.returncode}):\n{result.stdout[-2000:]}\n{err[-2000:]}"
    assert "Traceback" not in err, err[-3000:]
    for needle in needles:
        assert needle in err, f"{needle!r} not in:\n{err[-3000:]}"
    return err


def files_under(folder: Path) -> dict[str, bytes]:
    """Every file below `folder` with its bytes (what a failed run must leave unchanged)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def cli():
    return run_cli
