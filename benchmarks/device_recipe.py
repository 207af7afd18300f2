"""A recipe's data on every core of one machine: `factory.dataset build --recipe NAME`'s folders, made
by a pool of worker processes, one task each at a time, Cycles on one thread per worker.

    python3.11 benchmarks/device_recipe.py all_garments --out /tmp/data/all_garments [--workers 10 --gpu-workers 6]

On the GPU machine this runs under the relocated Python (`benchmarks/device_factory.py`), detached:

    . /tmp/fenv/env.sh && mkdir -p /tmp/data
    setsid nohup python3.11 benchmarks/device_recipe.py all_garments --out /tmp/data/all_garments \\
        > /tmp/data/build.log 2>&1 < /dev/null &
    sleep 30; tail -3 /tmp/data/build.log

and is polled from later calls with `tail` of the log, ``OUT/factory_run.json`` (progress: simulations
and images done, images/hour, seconds per image) or
`python3 benchmarks/device_files.py wait OUT/factory_run.done --timeout 570` (written at the end).

Why not `factory.dataset build --recipe NAME` itself: it builds the recipe's parts one after the
other, each part's motions one after the other, and renders with every core in one process while the
ground truth (about as long as a render on 16 cores) runs on one; and N processes of
``--shard i/N`` would each simulate every motion.  Here the tasks are the build's own
(`factory.build.prepare`, `factory.shards`): per part, `prepare` and the first motion's simulation
(which dresses the garment the part's motions share), then its other motions, then `plan_shards` and
one `make_shard` per frame;
simulations go first, renders fill the free workers.  Each CPU worker renders with cores // workers
Cycles threads (1 on 16 workers), on the CPU: the GPU is hidden from it.  `--gpu-workers N` adds N
processes that take render tasks only and render with Cycles on the GPU (OptiX on the H200: 8,600
images an hour at 512 px with 8 of them, 5x the 16 cores); Cycles compiles its GPU kernels for the
H200 in about 8 minutes unless the driver's cache (``CUDA_CACHE_PATH``, ``CUDA_CACHE_MAXSIZE`` of a
few GiB; 32 MB) holds them from an earlier run, so carry it.  When every task is done,
`factory.recipe.build_recipe` runs once over the finished folders: it plans nothing more and writes
the recipe's record, each part's manifest, timing and contact sheet, exactly as a plain build does
(each part's ``timing.json`` then counts that pass, 0 images; ``factory_run.json`` has the build's).

A killed run resumes: rerun the same command (finished simulations and images are kept).  A task that
fails is logged with its traceback and its part's remaining tasks are dropped; the others go on, the
final pass is skipped and the exit status is 1.  A worker that dies (a crash in Blender) loses only
its task, which is tried again, twice at most.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
import traceback
from collections import deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

log = logging.getLogger("device_recipe")

STATUS, DONE = "factory_run.json", "factory_run.done"
#: attempts of a task whose worker died, after the first
RETRIES = 2
#: one thread per process for numpy/scipy's BLAS; no GPU for Cycles in the workers
WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "CUDA_VISIBLE_DEVICES": ""}


# ---- the tasks (in the workers) -----------------------------------------------------------------
def _simulate(config, folder: str, motion: str, first: bool) -> tuple[str, float]:
    """The simulation of `motion` in part `folder` (the first one prepares the folder and dresses)."""
    from factory.build import prepare
    from factory.shards import simulate_motion

    started = time.perf_counter()
    if first:
        prepare(config, Path(folder), (0, 1))
    return str(simulate_motion(config, folder, motion)), time.perf_counter() - started


def _render(config, folder: str, shard, threads: int) -> dict:
    from factory.shards import make_shard

    return make_shard(config, folder, shard, threads=threads)


# ---- the schedule (in the main process) ---------------------------------------------------------
@dataclass
class _Part:
    folder: str
    config: object
    motions: tuple[str, ...]
    images: int
    sequences: dict = field(default_factory=dict)
    renders_left: int = 0
    failed: str | None = None


@dataclass
class _Task:
    kind: str  # "simulate" or "render"
    part: _Part
    args: tuple
    attempts: int = 0


class RecipeRun:
    """The schedule and its record: tasks waiting (simulations first), running, and what is done."""

    def __init__(self, name: str, out: Path, workers: int, train_only: bool, gpu_workers: int = 0):
        from factory.shards import dataset_frames
        from factory.recipe import HOLDOUT, load_data_recipe

        self.name, self.out, self.workers, self.train_only = name, Path(out), workers, train_only
        self.gpu_workers = gpu_workers
        self.threads = max(1, (os.cpu_count() or 1) // workers)
        _, _, recipe = load_data_recipe(name)
        self.parts = [_Part(str(self.out / p.folder), p.config, p.config.motions,
                            len(p.config.motions) * len(dataset_frames(p.config)) * p.config.variations)
                      for p in recipe.parts() if not (train_only and p.folder.startswith(HOLDOUT))]
        self.simulations = deque(_Task("simulate", p, (p.config, p.folder, p.motions[0], True)) for p in self.parts)
        self.renders: deque[_Task] = deque()
        self.started = time.perf_counter()
        self.done = {"simulations": 0, "images": 0, "simulate_s": 0.0, "render_s": 0.0, "groundtruth_s": 0.0,
                     "setup_s": 0.0}
        self.failures: list[dict] = []

    def next_render(self) -> _Task | None:
        """The next render task (a GPU worker's), None when none is waiting."""
        while self.renders:
            task = self.renders.popleft()
            if task.part.failed is None:
                return task
        return None

    def next_task(self) -> _Task | None:
        for queue in (self.simulations, self.renders):
            while queue:
                task = queue.popleft()
                if task.part.failed is None:
                    return task
        return None

    def finished(self, task: _Task, result) -> None:
        part = task.part
        if task.kind == "simulate":
            motion = task.args[2]
            part.sequences[motion], seconds = Path(result[0]), result[1]
            self.done["simulations"] += 1
            self.done["simulate_s"] += seconds
            log.info("simulated %s %s in %.0f s (%d of %d)", self._label(part), motion, seconds,
                     self.done["simulations"], self.total_simulations)
            if task.args[3]:
                self.simulations.extendleft(reversed([_Task("simulate", part, (part.config, part.folder, m, False))
                                                      for m in part.motions[1:]]))
            if len(part.sequences) == len(part.motions):
                self._plan(part)
        else:
            part.renders_left -= 1
            for key in ("images", "render_s", "groundtruth_s", "setup_s"):
                self.done[key] += result[key]
            log.info("rendered %s %s: %d images (%d of %d, %.0f an hour)", self._label(part), task.args[2].name,
                     result["images"], self.done["images"], self.total_images, self.images_per_hour)
            if part.renders_left == 0:
                log.info("part %s done", self._label(part))

    def _plan(self, part: _Part) -> None:
        from factory.shards import plan_shards

        shards = plan_shards(part.config, Path(part.folder), part.sequences, (0, 1), 1)
        part.renders_left = len(shards)
        self.renders.extend(_Task("render", part, (part.config, part.folder, s, self.threads)) for s in shards)
        if not shards:
            log.info("part %s: every image was already made", self._label(part))

    def failed(self, task: _Task, error: str) -> None:
        task.part.failed = error
        self.failures.append({"part": self._label(task.part), "task": task.kind, "error": error})
        log.error("%s of part %s failed; its other tasks are dropped:\n%s", task.kind, self._label(task.part), error)

    def _label(self, part: _Part) -> str:
        return Path(part.folder).relative_to(self.out).as_posix()

    @property
    def total_simulations(self) -> int:
        return sum(len(p.motions) for p in self.parts)

    @property
    def total_images(self) -> int:
        return sum(p.images for p in self.parts)

    @property
    def images_per_hour(self) -> float:
        return self.done["images"] / max(time.perf_counter() - self.started, 1e-9) * 3600

    def record(self, finished: bool = False) -> dict:
        images = max(self.done["images"], 1)
        return {"recipe": self.name, "out": str(self.out), "workers": self.workers,
                "gpu_workers": self.gpu_workers, "render_threads": self.threads,
                "cores": os.cpu_count(), "parts": len(self.parts), "train_only": self.train_only,
                "simulations": [self.done["simulations"], self.total_simulations],
                "images": [self.done["images"], self.total_images], "images_per_hour": round(self.images_per_hour, 1),
                "wall_s": round(time.perf_counter() - self.started, 1),
                "simulate_s_mean": round(self.done["simulate_s"] / max(self.done["simulations"], 1), 1),
                "render_s_per_image": round(self.done["render_s"] / images, 2),
                "groundtruth_s_per_image": round(self.done["groundtruth_s"] / images, 2),
                "setup_s": round(self.done["setup_s"], 1), "failures": self.failures, "finished": finished}


def _show_gpu() -> None:
    """A GPU worker's initializer: Cycles there sees the GPU the main process hides from CPU workers."""
    os.environ.pop("CUDA_VISIBLE_DEVICES", None)


def _pool(workers: int, gpu: bool = False) -> ProcessPoolExecutor:
    import multiprocessing

    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_show_gpu if gpu else None)


def run_recipe(name: str, out: Path, workers: int | None = None, train_only: bool = False,
               gpu_workers: int = 0) -> dict:
    """Build recipe `name`'s data in `out` on `workers` CPU processes (default: one per core) and
    `gpu_workers` processes whose Cycles renders on the GPU (render tasks only; Cycles' kernels for the
    GPU are compiled once per machine: keep ``CUDA_CACHE_PATH`` and a large ``CUDA_CACHE_MAXSIZE``);
    returns ``factory_run.json``'s record."""
    from assets.fileio import save_json

    os.environ.update(WORKER_ENV)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    workers = workers or os.cpu_count() or 1
    run = RecipeRun(name, out, workers, train_only, gpu_workers)
    log.info("recipe %s: %d parts, %d simulations, %d images on %d workers (%d Cycles threads each) and %d GPU "
             "workers", name, len(run.parts), run.total_simulations, run.total_images, workers, run.threads,
             gpu_workers)
    functions = {"simulate": _simulate, "render": _render}
    sizes = {"cpu": workers, "gpu": gpu_workers}
    pools = {kind: _pool(size, kind == "gpu") for kind, size in sizes.items() if size}
    running: dict = {}  # future -> (task, pool kind)

    def busy(kind: str) -> int:
        return sum(1 for _, k in running.values() if k == kind)

    try:
        while True:
            for kind in pools:
                while busy(kind) < sizes[kind]:
                    task = run.next_task() if kind == "cpu" else run.next_render()
                    if task is None:
                        break
                    args = task.args if kind == "cpu" or task.kind != "render" else (*task.args[:3], 1)
                    running[pools[kind].submit(functions[task.kind], *args)] = (task, kind)
            if not running:
                break
            ready, _ = wait(running, return_when=FIRST_COMPLETED)
            broken: dict[str, list] = {}
            for future in ready:
                task, kind = running.pop(future)
                try:
                    run.finished(task, future.result())
                except BrokenProcessPool:
                    broken.setdefault(kind, []).append(task)
                except Exception:
                    run.failed(task, traceback.format_exc())
            for kind, lost in broken.items():  # a worker died: that pool's tasks in flight are lost; retry them
                lost += [t for f, (t, k) in list(running.items()) if k == kind]
                for future in [f for f, (_, k) in running.items() if k == kind]:
                    del running[future]
                pools[kind].shutdown(cancel_futures=True)
                pools[kind] = _pool(sizes[kind], kind == "gpu")
                for task in lost:
                    task.attempts += 1
                    if task.attempts > RETRIES:
                        run.failed(task, f"its worker died {task.attempts} times")
                    else:
                        (run.simulations if task.kind == "simulate" else run.renders).appendleft(task)
            save_json(out / STATUS, run.record())
    finally:
        for pool in pools.values():
            pool.shutdown(cancel_futures=True)
    if not run.failures:
        from factory.recipe import build_recipe

        build_recipe(name, out, holdout=not train_only)
    record = run.record(finished=True)
    save_json(out / STATUS, record)
    save_json(out / DONE, record)
    log.info("%d images in %.0f s: %.0f an hour; %d failed tasks", record["images"][0], record["wall_s"],
             record["images_per_hour"], len(run.failures))
    return record


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recipe", help="a recipe name (networks/recipes/NAME.toml) or a .toml file")
    parser.add_argument("--out", type=Path, required=True, help="the recipe's data folder (resumes what is there)")
    parser.add_argument("--workers", type=int, help="worker processes (default: one per core)")
    parser.add_argument("--gpu-workers", type=int, default=0, metavar="N",
                        help="processes rendering on the GPU (render tasks only; default 0)")
    parser.add_argument("--train-only", action="store_true", help="the recipe's training parts only")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.workers is not None and args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    try:
        record = run_recipe(args.recipe, args.out, args.workers, args.train_only, max(args.gpu_workers, 0))
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 1 if record["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
