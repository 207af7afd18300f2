"""Worker processes of data loading and shard writing: one thread each, forked from a fork server.

Workers forked from the caller would inherit its initialised OpenBLAS and run a pool of every core in
each worker (synthesis measured 8-17x slower with 14 workers on 16 cores), and OpenCV or CUDA state
inherited by a fork can deadlock.  Spawned workers avoid both, but each imports the caller's main
module and torch again: on the GPU machine 31 workers starting at once took 48 s before their first
part (importing `networks.shards` alone takes 8 s there), against 9 s for the
part itself.  So workers come from a fork server (`worker_context`): one fresh interpreter, started
inside `server_environment` (one BLAS / OpenMP thread, read at import), that imports torch, the
caller's main module and the named modules once and forks each worker from that clean state; each
worker calls `one_thread` first.  Where there is no fork server (Windows), workers are spawned and
take the caller's thread settings (set OMP_NUM_THREADS=1 and OPENBLAS_NUM_THREADS=1 there).

multiprocessing's own "__main__" preload does nothing (Python 3.11 and 3.12 pass the server no path
of the main module), so the main module is preloaded by its name when it was run with `python -m`
(`python -m networks.train`: without it every DataLoader worker imported torch and the trainer's
modules anew, and the first batch came 30 s after the loop began on the GPU machine, against 3.5 s
for workers of a preloaded server); a script's own imports are covered by
torch and the named modules.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import sys
from multiprocessing import forkserver
from multiprocessing.context import BaseContext

import cv2

#: environment of the workers: one BLAS / OpenMP thread each (the workers are the parallelism)
WORKER_THREADS_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def one_thread(*_: object) -> None:
    """Worker initialiser: one OpenCV thread.  Accepts and ignores a DataLoader's worker id."""
    cv2.setNumThreads(1)


#: the fork server's environment: the workers' threads, and quiet about a worker started for
#: `python -m module` running that module again as __mp_main__ (multiprocessing's preparation) after
#: the server's preload imported it, which runpy warns about on every worker
SERVER_ENV = {**WORKER_THREADS_ENV, "PYTHONWARNINGS": "ignore::RuntimeWarning:runpy"}


@contextlib.contextmanager
def server_environment():
    """`SERVER_ENV` set while the fork server starts, then the caller's environment restored."""
    saved = {k: os.environ.get(k) for k in SERVER_ENV}
    os.environ.update(SERVER_ENV)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def preload_modules(*modules: str) -> list[str]:
    """What the fork server imports before forking workers: torch, the main module by name when it
    was run with `python -m` (not a package's __main__, whose import would run it), then `modules`
    ("__main__" among them is dropped: multiprocessing's preload of it does nothing)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    main = getattr(spec, "name", None)
    named = [main] if main and main != "__main__" and not main.endswith(".__main__") else []
    chosen = ["torch", *named, *(m for m in modules if m != "__main__")]
    return list(dict.fromkeys(chosen))


def worker_context(*modules: str) -> BaseContext:
    """The multiprocessing context for workers: the fork server (started now, in `server_environment`,
    preloading `preload_modules(*modules)`: `modules` name the ones holding the workers' functions),
    or spawn where there is none.  The server is one per process: the first call's modules stay."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(preload_modules(*modules))
    with server_environment():
        forkserver.ensure_running()
    return context
