"""Pre-synthesized training data: shard folders of `PatternSynthesizer` samples for one task.

    python -m networks.shards write --out shards/localizer --task localizer --count 20000 --workers 15 \\
        --garment out/ds --image-size 256

Synthesizing on the fly in DataLoader workers feeds a GPU poorly (about 50 localizer images/s from 3
workers) and is paid again by every run and every epoch.  A
shard folder is written once by a pool of processes, then read by `networks.data.ShardDataset` from
memory-mapped .npy files, where a worker costs little more than the augmentation; several runs (the
data-mix comparison) and resumed runs share it.

Layout (`networks.data` defines the names): shards.json (format, task, pattern spec, codebook hash,
synthesizer config, the marker IDs drawn, images_per_part, crops_per_image) and part_NNNNN/ with the
arrays of `SHARD_ARRAYS[task]`.  Part p holds synthetic samples p * images_per_part ... (p + 1) *
images_per_part - 1 of the synthesizer (deterministic in its config and seed): the localizer's images
and cell targets, or up to crops_per_image crops of each image for the crop tasks (a random subset,
seeded by the sample).  A part is written under a .tmp name and renamed when complete, so an
interrupted writer leaves no half part, and writing again with a larger --count adds parts.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

import numpy as np
from tqdm import tqdm

from assets.fileio import record_stage
from assets.pattern.observation import localizer_targets
from assets.pattern.spec import PatternSpec
from networks.checkpoint import codebook_hash
from networks.config import TASKS
from networks.data import (SHARD_ARRAYS, SHARD_FORMAT, SHARD_META, dataset_spec, garment_marker_ids, read_shard_meta,
                           shard_parts, synth_crops)
from networks.flags import CROP_JITTER, SEED, WHOLE_MARKERS_ONLY, add_config_flags, config_overrides
from networks.synth import PatternSynthesizer, SynthConfig
from networks.workers import one_thread, worker_context

log = logging.getLogger(__name__)

VERSION = 1
#: the SynthConfig fields `python -m networks.shards write` sets by flags (`networks.flags`; the image
#: size is a flag of its own, one side for a square)
SHARD_FLAGS = (SEED, CROP_JITTER, WHOLE_MARKERS_ONLY)
#: the generator part of the crop subset of a sample (distinct from the synthesizer's parts)
_SUBSET = 101

_worker: dict = {}


def _start_worker(task: str, spec: dict, config: dict, codebook: np.ndarray, marker_ids: list | None,
                  images_per_part: int, crops_per_image: int) -> None:
    one_thread()
    spec = PatternSpec.from_dict(spec)
    _worker.update(task=task, spec=spec, images_per_part=images_per_part, crops_per_image=crops_per_image,
                   synth=PatternSynthesizer(spec, SynthConfig.from_dict(config), codebook, marker_ids))


def _write_part(root: str, number: int) -> tuple[int, int, float]:
    """Synthesize part `number` into root/part_NNNNN (atomically); returns (number, items, seconds)."""
    started = time.perf_counter()
    task, spec, synth = _worker["task"], _worker["spec"], _worker["synth"]
    count = _worker["images_per_part"]
    columns: dict[str, list[np.ndarray]] = {name: [] for name in SHARD_ARRAYS[task]}
    for index in range(number * count, (number + 1) * count):
        image, gt = synth.sample(index)
        if task == "localizer":
            columns["image"].append(image[None])
            columns["cells"].append(localizer_targets(gt)[None])
            continue
        rng = np.random.default_rng([synth.config.seed, index, _SUBSET])

        def keep(crops: int) -> np.ndarray:  # the image's crops kept, drawn from its seed (called at once)
            return np.sort(rng.permutation(crops)[:_worker["crops_per_image"]])

        for name, array in zip(SHARD_ARRAYS[task], synth_crops(task, image, gt, spec, synth.config, index, keep)):
            columns[name].append(array)
    final = Path(root) / f"part_{number:05d}"
    tmp = final.with_suffix(".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for name, arrays in columns.items():
        np.save(tmp / f"{name}.npy", np.concatenate(arrays))
    os.replace(tmp, final)
    return number, sum(len(a) for a in columns[SHARD_ARRAYS[task][0]]), time.perf_counter() - started


def shard_meta(task: str, spec: PatternSpec, config: SynthConfig, marker_ids: np.ndarray | None,
               images_per_part: int, crops_per_image: int) -> dict:
    """The shards.json record of a shard folder (plain JSON types); crop_geometry: how the crop tasks'
    crops are cut (`assets.pattern.CropGeometry`; None for the localizer's images)."""
    return json.loads(json.dumps({
        "format": SHARD_FORMAT, "version": VERSION, "task": task, "spec": spec.to_dict(),
        "codebook_hash": codebook_hash(spec), "synth": config.to_dict(),
        "crop_geometry": None if task == "localizer" else config.crop_geometry().to_dict(),
        "marker_ids": None if marker_ids is None else [int(i) for i in marker_ids],
        "images_per_part": int(images_per_part), "crops_per_image": int(crops_per_image)}))


def write_shards(out: str | Path, task: str, spec: PatternSpec, count: int, config: SynthConfig = SynthConfig(),
                 marker_ids: np.ndarray | None = None, workers: int = 1, images_per_part: int = 64,
                 crops_per_image: int = 32, time_limit_s: float | None = None, progress: bool = True) -> dict:
    """Write the parts of `count` synthetic images (rounded up to whole parts) that `out` lacks.

    task: one of `TASKS`; spec and config: the pattern and the synthesizer (its seed included);
    marker_ids: the IDs drawn (default all of the codebook); workers: processes of one thread each
    (`networks.workers`); time_limit_s: submit no part that would end after that many seconds (a part's time is the
    median of those finished; parts under way finish; an empty folder gets one part whatever the
    limit).  The folder's shards.json records the settings (`shard_meta`, through
    `assets.fileio.record_stage`): a folder written before with other settings is refused, naming them.  Returns {"parts", "items" (in the
    folder), "written_parts", "written_images", "seconds", "images_per_s", "images_per_s_per_worker",
    "complete", "worker_seconds_per_image" (a worker's median time per image of a part, its start
    excluded; None when none was written), "first_part_s" (seconds to the first finished part, the
    workers' start included; None when none was written), "busy" (the share of the pool's time spent
    in parts)}."""
    if task not in TASKS:
        raise ValueError(f"task must be one of {', '.join(TASKS)}, got {task!r}")
    if count < 1 or workers < 1 or images_per_part < 1 or crops_per_image < 1:
        raise ValueError(f"count, workers, images_per_part and crops_per_image must be >= 1, got {count}, "
                         f"{workers}, {images_per_part}, {crops_per_image}")
    out = Path(out)
    meta = shard_meta(task, spec, config, marker_ids, images_per_part, crops_per_image)
    if (out / SHARD_META).exists():
        read_shard_meta(out)  # a shard folder at all
    record_stage(out / SHARD_META, meta)
    done = {int(p.name.split("_")[1]) for p in shard_parts(out)}
    todo = [n for n in range(-(-count // images_per_part)) if n not in done]
    started = time.perf_counter()
    pool_size = min(workers, max(1, len(todo)))
    part_s = []  # each written part's time in its worker (the worker's start excluded)
    first_s = None  # from the start to the first finished part (the workers' start included)
    if todo:
        codebook = PatternSynthesizer(spec, config).codebook  # once here, not in every worker
        initargs = (task, spec.to_dict(), config.to_dict(), codebook, meta["marker_ids"], images_per_part,
                    crops_per_image)
        bar = tqdm(total=len(todo), desc=f"shards {task}", unit="part", disable=not progress)
        with ProcessPoolExecutor(pool_size, mp_context=worker_context("networks.shards"), initializer=_start_worker,
                                 initargs=initargs) as pool:
            pending, queue = set(), list(todo)
            while queue or pending:
                # one part per worker, submitted only while it would end within the limit (a part's
                # time: the median of the finished ones), so the limit holds to within one part
                while queue and len(pending) < pool_size:
                    ahead = np.median(part_s) if part_s else 0.0
                    late = time_limit_s is not None and time.perf_counter() - started + ahead > time_limit_s
                    if late and (done or part_s or pending):  # an empty folder gets one part at least
                        break
                    pending.add(pool.submit(_write_part, str(out), queue.pop(0)))
                if not pending:
                    break
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in finished:
                    part_s.append(future.result()[2])
                    bar.update(1)
                if first_s is None:
                    first_s = time.perf_counter() - started
        bar.close()
    written = len(part_s)
    seconds = time.perf_counter() - started
    parts = shard_parts(out)
    key = SHARD_ARRAYS[task][0]
    items = sum(len(np.load(p / f"{key}.npy", mmap_mode="r")) for p in parts)
    rate = written * images_per_part / seconds if written else 0.0
    have = {int(p.name.split("_")[1]) for p in parts}
    return {"task": task, "parts": len(parts), "items": items, "written_parts": written,
            "written_images": written * images_per_part, "seconds": seconds, "images_per_s": rate,
            "images_per_s_per_worker": rate / pool_size, "first_part_s": first_s,
            "busy": sum(part_s) / (pool_size * seconds) if written else 0.0,
            "complete": set(range(-(-count // images_per_part))) <= have,
            "worker_seconds_per_image": float(np.median(part_s)) / images_per_part if part_s else None}


def main(argv: list[str] | None = None) -> int:
    """`python -m networks.shards write ...`: pre-synthesize a shard folder."""
    from assets.cli import add_out, add_progress, add_workers, progress, run_cli

    parser = argparse.ArgumentParser(prog="python -m networks.shards", description="Pre-synthesized training data.")
    commands = parser.add_subparsers(dest="command", required=True)
    write = commands.add_parser("write", help="write (or extend) a shard folder of pre-synthesized samples",
                                description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_out(write, "the shard folder (extended when it holds shards of the same settings)")
    write.add_argument("--task", choices=TASKS, required=True, help="the network whose items to write")
    write.add_argument("--count", type=int, required=True, help="synthetic images (rounded up to whole parts)")
    add_workers(write, "processes, one thread each", default=1)
    write.add_argument("--garment", type=Path, help="a factory dataset folder or template.npz: its pattern, and "
                       "only its garment's marker IDs (unless --all-ids)")
    write.add_argument("--pattern", type=Path, help="PatternSpec JSON (default: the garment's, else PatternSpec())")
    write.add_argument("--all-ids", action="store_true", help="draw every codebook ID, not only the garment's")
    write.add_argument("--config", type=Path, help="SynthConfig JSON (fields given override the defaults)")
    write.add_argument("--image-size", type=int, metavar="PX",
                       help="side of the synthesized images, pixels (SynthConfig.image_size)")
    add_config_flags(write, SynthConfig, SHARD_FLAGS)
    write.add_argument("--images-per-part", type=int, default=64)
    write.add_argument("--crops-per-image", type=int, default=32, help="crop tasks: crops kept per image")
    write.add_argument("--time-limit", type=float, help="start no part after this many seconds")
    add_progress(write)
    args = parser.parse_args(argv)

    def action() -> None:
        config = SynthConfig() if args.config is None else SynthConfig.from_dict(
            json.loads(args.config.read_text()), source=str(args.config))
        if args.image_size is not None:
            config = config.replace(image_size=(args.image_size, args.image_size))
        config = config.replace(**config_overrides(args, SHARD_FLAGS))
        if args.pattern is not None:
            spec = PatternSpec.load(args.pattern)
        else:
            spec = dataset_spec(args.garment) if args.garment is not None else PatternSpec()
        ids = garment_marker_ids(args.garment) if args.garment is not None and not args.all_ids else None
        result = write_shards(args.out, args.task, spec, args.count, config, ids, args.workers,
                              args.images_per_part, args.crops_per_image, args.time_limit, progress(args))
        print(f"{args.out}: {result['parts']} parts, {result['items']} {args.task} items "
              f"({'complete' if result['complete'] else 'incomplete: run again to continue'}); wrote "
              f"{result['written_images']} images in {result['seconds']:.0f} s = {result['images_per_s']:.1f} "
              f"images/s ({result['images_per_s_per_worker']:.1f} per worker)"
              + (f"; first part after {result['first_part_s']:.1f} s, {result['worker_seconds_per_image'] * 1e3:.0f} "
                 f"ms per image in a worker, workers busy {result['busy']:.0%}" if result['written_parts'] else ""))

    return run_cli(action)


if __name__ == "__main__":
    sys.exit(main())
