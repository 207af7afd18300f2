"""Workers come from a fork server started with one BLAS / OpenMP thread, whatever the caller's setting."""

import os
import sys
from concurrent.futures import ProcessPoolExecutor

import pytest

from networks.workers import WORKER_THREADS_ENV, worker_context


def _environment() -> dict:
    return {k: os.environ.get(k) for k in WORKER_THREADS_ENV}


@pytest.mark.skipif(sys.platform == "win32", reason="no fork server on Windows")
def test_workers_have_one_thread_and_the_caller_keeps_its_setting(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    context = worker_context(__name__)
    assert context.get_start_method() == "forkserver"
    with ProcessPoolExecutor(2, mp_context=context) as pool:
        seen = [pool.submit(_environment).result() for _ in range(2)]
    assert seen == [WORKER_THREADS_ENV] * 2
    assert os.environ["OMP_NUM_THREADS"] == "7"
