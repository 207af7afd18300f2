"""Worker processes of data loading and shard writing: spawned interpreters with one thread each.

Forked workers would inherit the parent's initialised OpenBLAS and run a pool of every core in each
worker (synthesis measured 8-17x slower with 14 workers on 16 cores), and OpenCV or CUDA state
inherited by a fork can deadlock.  So workers are spawned inside `worker_environment` (they read the
thread variables at import) and call `one_thread` first.
"""

from __future__ import annotations

import contextlib
import os

import cv2

#: environment of the workers: one BLAS / OpenMP thread each (the workers are the parallelism)
WORKER_THREADS_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def one_thread(*_: object) -> None:
    """Worker initialiser: one OpenCV thread (safe in a spawned worker; in a forked one it can
    deadlock, see `networks.data`).  Accepts and ignores a DataLoader's worker id."""
    cv2.setNumThreads(1)


@contextlib.contextmanager
def worker_environment():
    """`WORKER_THREADS_ENV` set while workers start, then the caller's environment restored."""
    saved = {k: os.environ.get(k) for k in WORKER_THREADS_ENV}
    os.environ.update(WORKER_THREADS_ENV)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
