"""Workers come from a fork server started with one BLAS / OpenMP thread, whatever the caller's
setting, that has imported the caller's modules, the main module of a `python -m` run among them."""

import os
import subprocess
import sys
import textwrap
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from networks.workers import WORKER_THREADS_ENV, preload_modules, worker_context

ROOT = Path(__file__).resolve().parents[2]


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


@pytest.mark.skipif(sys.platform == "win32", reason="no fork server on Windows")
def test_a_python_m_main_module_is_preloaded_so_workers_inherit_its_imports(tmp_path):
    # `heavy` stands for torch and the trainer's modules: imported by the main module, it records the
    # process that imported it; a worker that inherited it from the server sees another process's id
    (tmp_path / "heavy.py").write_text("import os\nPID = os.getpid()\n")
    (tmp_path / "probe_main.py").write_text(textwrap.dedent("""
        import os
        from concurrent.futures import ProcessPoolExecutor

        import heavy
        from networks.workers import worker_context


        def probe(_):
            return heavy.PID != os.getpid()


        if __name__ == "__main__":
            with ProcessPoolExecutor(2, mp_context=worker_context("__main__")) as pool:
                print("INHERITED", all(pool.map(probe, range(4))))
    """))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(tmp_path)])}
    done = subprocess.run([sys.executable, "-m", "probe_main"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "INHERITED True" in done.stdout


def test_preload_names_torch_the_modules_and_never_main():
    chosen = preload_modules("__main__", "networks.shards", "networks.shards")
    assert chosen[0] == "torch" and chosen.count("networks.shards") == 1 and "__main__" not in chosen
