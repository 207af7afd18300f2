"""The dataset build as Ray tasks (`python -m factory.dataset build ... --backend ray`).

The same tasks as the local backend (`factory.build`): one simulation per motion of the dataset's
(garment, body), then one render + ground-truth task per `Shard`, each declaring what it needs (a
CPU; a GPU for Cycles when the cluster has one).  Ray retries a task whose worker dies or which
raises (`max_retries`); a shard commits its images' records only when all of its files are written
(`factory.shards.make_shard`), so a retried or repeated task adds no duplicate and no partial
record, and a restarted build plans only the unfinished images.  Every node reads and writes the
dataset folder, so on a cluster it must be shared storage at the same path on every node.
"""

from __future__ import annotations

import math
import os
import shutil
import uuid
from pathlib import Path

from factory.plan import DatasetConfig
from factory.shards import BuildProgress, Shard, make_shard, simulate_motion

#: attempts of a task after the first (a killed worker, an exception)
MAX_RETRIES = 3


def _import_ray():
    try:
        import ray
    except ImportError:
        raise RuntimeError("--backend ray needs Ray: pip install '.[ray]'") from None
    return ray


def _shard_attempt(config: DatasetConfig, out: str, shard: Shard, threads: int = 0) -> dict:
    """One attempt at a shard, rendering with `threads` threads: `make_shard`'s timing plus ``retried``,
    the attempts before this one that never finished (each attempt leaves a mark in
    ``jobs/<shard>.attempts/`` until one succeeds)."""
    attempts = Path(out) / "jobs" / f"{shard.name}.attempts"
    attempts.mkdir(parents=True, exist_ok=True)
    earlier = sum(1 for _ in attempts.iterdir())
    (attempts / f"{os.getpid()}-{uuid.uuid4().hex}").touch()
    timing = make_shard(config, out, shard, threads=threads)
    shutil.rmtree(attempts, ignore_errors=True)
    return {**timing, "retried": earlier}


class RayBackend:
    """Tasks on the Ray cluster at `address` (joined), or on a local Ray instance (started here and
    stopped at the end) of `workers` CPUs, default one per core: as many tasks at once, each declaring
    `task_cpus` CPUs."""

    def __init__(self, address: str | None = None, workers: int | None = None, task_cpus: float = 1.0,
                 max_retries: int = MAX_RETRIES):
        self.address, self.workers, self.task_cpus, self.max_retries = address, workers, task_cpus, max_retries
        self.ray = None
        self.started = False

    def __enter__(self) -> "RayBackend":
        self.ray = ray = _import_ray()
        if not ray.is_initialized():
            if self.address:
                ray.init(address=self.address, log_to_driver=False)
            else:
                ray.init(num_cpus=self.workers or os.cpu_count(), include_dashboard=False, log_to_driver=False)
            self.started = True
        return self

    def __exit__(self, *exc) -> None:
        if self.started:
            self.ray.shutdown()

    def _task(self, function, **resources):
        return self.ray.remote(num_cpus=self.task_cpus, max_retries=self.max_retries, retry_exceptions=True,
                               **resources)(function)

    def _gather(self, refs: dict, bar: BuildProgress) -> dict:
        """ray.get of every ref as it finishes, ticking `bar`; {key: result}."""
        keys = {ref: key for key, ref in refs.items()}
        results, waiting = {}, list(keys)
        while waiting:
            ready, waiting = self.ray.wait(waiting, num_returns=1)
            for ref in ready:
                result = results[keys[ref]] = self.ray.get(ref)
                if isinstance(result, dict):
                    bar.done(result["images"], result["retried"])
                else:
                    bar.done()
        return results

    def simulate(self, config: DatasetConfig, out: Path, bar: BuildProgress) -> dict[str, Path]:
        task = self._task(simulate_motion)
        return self._gather({m: task.remote(config, str(out), m) for m in config.motions}, bar)

    def make_shards(self, config: DatasetConfig, out: Path, shards: list[Shard], bar: BuildProgress) -> list[dict]:
        cycles_on_gpu = (config.render.engine == "CYCLES" and config.render.device != "CPU"
                         and self.ray.cluster_resources().get("GPU", 0) >= 1)
        task = self._task(_shard_attempt, num_gpus=1 if cycles_on_gpu else 0)
        # Cycles on the CPU renders on every core: a task keeps to the CPUs it declared
        threads = 0 if cycles_on_gpu else max(1, math.ceil(self.task_cpus))
        results = self._gather({s.name: task.remote(config, str(out), s, threads) for s in shards}, bar)
        return [results[s.name] for s in shards]
