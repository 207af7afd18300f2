"""Benchmark the three networks (issue 7) on a GPU machine: train, evaluate on Blender renders, time
inference.  One call fits a 10-minute device command; calling it again with the same --out continues.

1. Shards.  Pre-synthesize training samples (`networks.shards`) with every core: 256 x 256 localizer
   images, recognizer and crosspoint crops, drawing the garment's marker IDs.  Written once (capped
   at --shard-minutes per call; an unfinished folder is continued by the next call and used as far
   as it goes), shared by all runs and calls.
2. Train, all runs at once, each resuming from its last.pt (`networks.train`), spread over the GPUs
   (`placement`: one GPU per main run while there are GPUs, a comparison run on the least loaded; with
   --ddp, spare GPUs join the heaviest main runs as DistributedDataParallel ranks through torchrun,
   which is off by default because it slows training down: on H200s the crosspoint network trains
   on synthetic shards at 31 steps/s on one GPU and 15 on two ranks, SyncBatchNorm included).  The main runs
   (`MAIN`, the default of --runs): localizer_mix (the rendered train split alone, synth weight 0),
   recognizer_partial (rendered crops + shards, synth weight 0.25) and crosspoints_rendered (rendered
   crops + shards, synth weight 0.25), their crops
   cut from five points jittered by `CROP_JITTER_PX`, as the Detector cuts them from the
   localizer's: shards written so, rendered crops cut anew per item, `TrainConfig.crop_jitter_px`;
   the jittered recognizer reached a validation loss of 0.164 on exact rendered crops against 0.263
   for the exact-crop one at the same step; the recognizer's crops include partial markers with a
   visible centre, `TrainConfig.recognizer_partial`, since a whole-marker recognizer read them 0.37
   right) train until the budget's end.
   Comparison runs, named in --runs: recognizer and crosspoints on the reference's exact crops,
   recognizer_jitter (jittered crops of whole markers only), crosspoints_jitter (the main
   crosspoint run's crops at synth weight 0.75: which mix trains it best), localizer_upright
   (the main localizer's config on synthesized markers all near upright, `SHARD_SYNTH`, as the
   renders' are), recognizer_small (the main recognizer's config on synthesized markers from 10 px,
   `SHARD_SYNTH`: markers under 16 px are where it errs), and
   the data-mix runs localizer_synth (shards only) and localizer_rendered (rendered only), which
   share the main localizer's config and stop at step COMPARE_STEPS, so all three are compared at
   that step (validation on the rendered val split, logged every VAL_EVERY steps).  A run that
   starts from a trained checkpoint (--init) peaks at LR as well (--init-lr for another).  Data workers
   are sized to the cores.  The schedule's planned steps are long (the learning rate stays near its
   peak); `--final` has each main run fit its schedule to end within this call (`networks.train
   --fit-time-limit`: the step rate measured early in the call, then again), so its cosine decay completes; one
   `--final` call on a fresh folder is a whole benchmark.
3. Evaluate each run's last.pt on the rendered dataset's validation and test images (`--rendered`, a
   factory dataset folder of Blender renders, read through a view in --out whose `samples/` are
   built there from the images and saved ground truth when the folder has none, so only images, gt,
   the manifest and template.npz need to travel and the folder itself is left as it is), and each
   checkpoint the runs started from (--init) beside them, the call's baseline; the three
   main runs chained as `networks.Detector`; and each recognizer's top-1 given the true points,
   whole against partial markers, beside the checkpoint the main recognizer started from (--init);
   and each run and its --init on held-out synthesized samples (`synth_heldout`: the shard folders'
   configs from another seed), where the gap between synthetic and rendered data shows; and the main
   localizer's presence threshold chosen on the val renders and checked beside the reference's 0.5
   on the test renders (`evaluate_threshold`).
4. Inference throughput of `networks.Detector` (the three main runs chained, float32) on synthesized
   images framed as the renders (markers scaled with the image side; the localizer sees them at the
   scale it was trained on, `DetectorConfig.localizer_scale` = 512 / side), on the GPU and on the CPU,
   which run the same first image (the number of markers found there must agree).

    python benchmarks/train_networks.py --rendered .bench/rendered --out /tmp/bn [--budget-minutes 9]
    python benchmarks/train_networks.py --rendered .bench/rendered --out /tmp/bn --final   # the last call

Each main run is also written as a compact int8 checkpoint and evaluated on the held-out renders
beside its float weights (`evaluate_compact`, "compact" in results.json): the form the repository
keeps (`networks.weights store`).
Trained networks leave the machine (checkpoints with Adam's state, about 1 GB, cannot):
`--export-weights` writes every trained run as a compact int8 checkpoint under <export>/store (the
main runs as <task>.pt, which `networks.weights store` takes, the comparison runs as <run>.pt, which
`--init` takes; localizer 12 MB, recognizer 33 MB, crosspoints 29 MB: int8 measured as the float
weights on the held-out renders, at half of bf16, so a comparison run that wins can come back too),
and they come back in checked parts over
back-to-back calls (`benchmarks/device_files.py`, whose docstring lists a session's calls: a call
returns at most 8 files of 16 MiB and carries at most 64 MiB, the machine goes back 30 s after a
call, and a path a call does not carry is removed from its working tree).  A later run starts from
them with `--init <folder>`, where they still exist: they are too large for the repository (its
working tree travels with every call), and a session may start from a new checkout without the
ignored folders of the last (16 parts of data and weights carry over in six 5-second calls).

Prints the tables of `benchmarks/RESULTS.md` and a `RESULT {json}` line; writes `results.json`, the
shards and the runs to `--out`.  `results.json` is written after training and after each evaluation
stage (`Stages`); a stage that fails leaves its traceback under "errors", the later ones still run, and
the call exits with an error at the end.  The rendered dataset must use the codebook this machine generates:
`--codebook-hash` (the hash printed on the machine that rendered it) stops the run early otherwise.
`--device cpu --max-steps N` is a smoke run (tiny shards and batches, runs one after another).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import shutil
import signal
import subprocess
import sys
import tarfile
import time
import traceback
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from assets.fileio import save_json, save_npz  # noqa: E402
from assets.pattern.observation import ImageGroundTruth, training_samples  # noqa: E402
from networks.checkpoint import codebook_hash, read_checkpoint, slim_checkpoint  # noqa: E402
from networks.config import TrainConfig  # noqa: E402
from networks.data import dataset_spec, garment_marker_ids, write_training_samples  # noqa: E402
from networks.evaluate import evaluate, evaluate_at, read_manifest  # noqa: E402
from networks.shards import write_shards  # noqa: E402
from networks.workers import one_thread, worker_context  # noqa: E402
from networks.synth import PatternSynthesizer, SynthConfig  # noqa: E402

#: per task: (planned steps over all calls, batch size); Adam at LR with WARMUP steps, cosine decay to
#: the planned step (shortened by --final to what the last call reaches: more than any call reaches)
SCHEDULE = {"localizer": (200_000, 32), "recognizer": (200_000, 256), "crosspoints": (200_000, 64)}
LR, WARMUP = 3e-4, 300
#: A run that starts from a trained checkpoint (`--init`) peaks at LR too (`--init-lr` for another):
#: a localizer fine-tuned at 5e-5 gained little, while at LR on the renders alone (decoded ahead) every
#: call gained (fully visible recall 0.884 -> 0.953 -> 0.980 -> 0.989, corners 0.93-1.02 -> 0.46-0.51 px).
#: side of the localizer's training images (rendered ones are cut to it), pixels
IMAGE_SIZE = 256
#: the data-mix comparison: the localizer runs compared at this step
COMPARE_STEPS = 1500
VAL_EVERY = {"localizer": 1000, "recognizer": 2000, "crosspoints": 2000}
#: name -> (task, synth weight, stop at step (None: the schedule), share of the data workers, shard folder)
RUNS = {
    # renders alone (named when it was half synthesized): on the renders alone it gains, while a
    # synthetic half held it back; `--synth-weight localizer_mix=0.5` brings the half back for a call
    "localizer_mix": ("localizer", 0.0, None, 3, "localizer"),
    "localizer_synth": ("localizer", 1.0, COMPARE_STEPS, 2, "localizer"),
    "localizer_rendered": ("localizer", 0.0, COMPARE_STEPS, 2, "localizer"),
    # the main localizer's config on synthesized markers turned as the renders' are (`SHARD_SYNTH`)
    "localizer_upright": ("localizer", 0.5, None, 3, "localizer_upright"),
    "recognizer": ("recognizer", 0.75, None, 6, "recognizer"),
    "recognizer_jitter": ("recognizer", 0.75, None, 6, "recognizer_jitter"),
    # the main recognizer: mostly rendered crops; at 0.75 synthesized it stayed at 0.984 on the held-out
    # renders over three calls, at 0.25 it reached 0.987 (beside recognizer_small at 0.5: 0.985);
    # `--synth-weight recognizer_partial=0.75` brings the old share back for a call
    "recognizer_partial": ("recognizer", 0.25, None, 6, "recognizer_partial"),
    # the main recognizer's config on synthesized markers from 10 px (`SHARD_SYNTH`): at 0.75 it read
    # 0.996 of the renders' fully visible markers of 16-24 px, 0.955 of 12-16 px and 0.78 under 12 px
    "recognizer_small": ("recognizer", 0.25, None, 6, "recognizer_small"),
    "crosspoints": ("crosspoints", 0.75, None, 3, "crosspoints"),
    "crosspoints_jitter": ("crosspoints", 0.75, None, 3, "crosspoints_jitter"),
    # the main crosspoint run: mostly rendered crops, which beat 0.75 synthesized from the same start on
    # the held-out renders twice (0.480 against 0.502 px); a rendered crop costs a worker more than a
    # shard's (decoded ahead, about 5 ms against 1.7): twice the share
    "crosspoints_rendered": ("crosspoints", 0.25, None, 6, "crosspoints_jitter"),
}
MAIN = {"localizer": "localizer_mix", "recognizer": "recognizer_partial", "crosspoints": "crosspoints_rendered"}
#: the jittered runs' crops are cut from five points jittered by this (pixels,
#: standard deviation; `SynthConfig.crop_jitter_px`): the localizer's corners are about 1.2 px off at
#: the median, 1.18 sigma for a 2D Gaussian
CROP_JITTER_PX = 1.0
#: shard folder -> (task, synthetic images (the crop tasks keep up to 32 crops of each), crop jitter px,
#: recognizer crops of partial markers too (`SynthConfig.recognizer_partial`, `TrainConfig.recognizer_partial`))
SHARDS = {"localizer": ("localizer", 19200, 0.0, False), "localizer_upright": ("localizer", 19200, 0.0, False),
          "recognizer": ("recognizer", 9600, 0.0, False),
          "recognizer_jitter": ("recognizer", 9600, CROP_JITTER_PX, False),
          "recognizer_partial": ("recognizer", 9600, CROP_JITTER_PX, True),
          "recognizer_small": ("recognizer", 9600, CROP_JITTER_PX, True),
          "crosspoints": ("crosspoints", 4800, 0.0, False),
          "crosspoints_jitter": ("crosspoints", 4800, CROP_JITTER_PX, False)}
#: shard folder -> SynthConfig fields that differ from the defaults.  localizer_upright: every marker
#: near upright (the defaults turn one in five uniformly: 17% of the synthesizer's fully visible
#: markers are turned past 45 degrees, 4.5% of the renders' and none of the capture's).
#: recognizer_small: markers from 10 px (the default's 16 px is the edge along the direction not foreshortened)
SHARD_SYNTH = {"localizer_upright": {"upright_probability": 1.0},
               "recognizer_small": {"marker_px": (10.0, 32.0)}}
#: held-out synthesized samples (`synth_heldout`): images per shard folder, synthesizer seed
SYNTH_HELDOUT = (64, 1_000_003)
#: a main run's GPU time per step against the localizer's (four runs sharing one H100: localizer
#: 15.3, recognizer 14.2, crosspoints 8.2 steps/s)
GPU_COST = {"localizer": 1.0, "recognizer": 1.1, "crosspoints": 1.9}
#: the tasks heaviest first: the order the main runs are placed in and take spare GPUs as DDP ranks
HEAVIEST = tuple(sorted(GPU_COST, key=GPU_COST.get, reverse=True))
#: steps between checkpoints (a ResNet-50 with its Adam state is about 300 MB to write)
CHECKPOINT_EVERY = 2000
#: smoke runs' Detector: only the surest guesses of an untrained localizer, far apart (hundreds of crops
#: through the crosspoint network take minutes on a CPU)
SMOKE_DETECTOR = {"presence_threshold": 0.9, "nms_radius_px": 40.0}
#: Detector settings timed beside its defaults in the throughput table (`throughput`): the crosspoint
#: smoothing's cost went unnoticed once (it cut 1024 px throughput on the H200 from 4.7 to 1.43 images/s)
THROUGHPUT_VARIANTS = {"no crosspoint smoothing": {"smooth_crosspoints_px": None}}
#: seconds kept after training for evaluation and throughput, and allowed for a run's start
RESERVE_S, START_S = 210.0, 45.0


def prepare(root: Path, out: Path, cores: int = 1, name: str = "rendered") -> tuple[Path, int]:
    """(a copy of the rendered dataset folder in `out`/`name`, samples built): its files copied, and
    `samples/<name>.npz` built in the copy (on `cores` processes) for every manifest entry when the
    folder has none.
    Copied, not linked: on the device machine the working tree is replaced by each call, and a call
    that does not carry the folder removes it there, so links into it break under a running
    benchmark and its evaluation is lost."""
    view = out / name
    view.mkdir(parents=True, exist_ok=True)
    items = ["images", "gt", "meta", "template.npz", "config.json", "splits.json", "manifest.jsonl"]
    for item in items + (["samples"] if (root / "samples").is_dir() else []):
        source, target = root / item, view / item
        if not source.exists() or target.exists():
            continue
        if source.is_dir():  # whole or not at all: an interrupted copy is finished by the next call
            partial = target.with_name(target.name + ".part")
            shutil.copytree(source, partial, dirs_exist_ok=True)
            partial.rename(target)
        else:
            shutil.copy2(source, target)
    spec = dataset_spec(view)
    entries = [json.loads(line) for line in (view / "manifest.jsonl").read_text().splitlines() if line]
    todo = [e for e in entries if not (view / e["samples"]).exists()]
    if cores > 1 and len(todo) > 1:
        # one thread each, from the fork server (`networks.workers`): forked from here, each process
        # ran every core's BLAS and OpenCV threads (load 2,800 on 64 cores, nothing built in a minute)
        with ProcessPoolExecutor(min(cores, len(todo)), mp_context=worker_context("networks.data"),
                                 initializer=one_thread) as pool:
            list(pool.map(functools.partial(write_training_samples, view, spec=spec), todo, chunksize=4))
    else:
        for entry in todo:
            write_training_samples(view, entry, spec)
    return view, len(todo)


def heldout(root: Path, out: Path, limit: int | None = None, markers: int | None = None, every_split: bool = False,
            name: str = "heldout") -> Path:
    """A view (`out`/`name`) of the rendered dataset holding its validation and test images (the first
    `limit`; every image with `every_split`: a folder of held-out renders only) as the split 'heldout'
    (the runs train on the train split of --rendered).  markers: keep only N markers of each image,
    fully visible ones first (smoke runs: evaluating every crop on a CPU takes minutes)."""
    view = out / name
    view.mkdir(parents=True, exist_ok=True)
    linked = ("images", "meta", "template.npz", "config.json", "splits.json") + (() if markers else ("gt", "samples"))
    for item in linked:
        link = view / item
        if not link.exists():
            link.symlink_to((root / item).resolve())
    entries = [json.loads(line) for line in (root / "manifest.jsonl").read_text().splitlines() if line]
    entries = [dict(e, split="heldout") for e in entries if every_split or e["split"] != "train"][:limit]
    if markers:
        spec = dataset_spec(root)
        for e in entries:
            gt = ImageGroundTruth.load(root / e["gt"])
            gt = gt.select(np.sort(np.argsort(-gt.status, kind="stable")[:markers]))  # fully visible first
            gt.save(view / e["gt"])
            image = cv2.imread(str(root / e["image"]), cv2.IMREAD_COLOR)[:, :, ::-1].copy()
            save_npz(view / e["samples"], training_samples(image, gt, spec))
    (view / "manifest.jsonl").write_text("".join(json.dumps(e) + "\n" for e in entries))
    return view


def run_step(folder: Path) -> int:
    """The step of a run folder's last.pt (0 when there is none)."""
    last = folder / "last.pt"
    return int(read_checkpoint(last)["step"]) if last.exists() else 0


def with_synth_weight(runs: dict[str, tuple], name: str, weight: float) -> dict[str, tuple]:
    """`runs` with run `name` drawing `weight` of its samples from the synthesizer (0: renders alone;
    `--localizer-synth-weight`: an A/B found a last renders-only phase, warped, lowers the
    localizer's corner error on renders from 1.04-1.11 to 0.78-0.81 px)."""
    if not 0 <= weight <= 1:
        raise ValueError(f"a synth weight must be in [0, 1], got {weight}")
    task, _, stop, share, folder = runs[name]
    return {**runs, name: (task, weight, stop, share, folder)}


def synth_weights(items: list[str], runs: dict[str, tuple]) -> dict[str, tuple]:
    """`runs` with each `RUN=W` of `items` (`--synth-weight`) drawing W of its samples from the
    synthesizer (`with_synth_weight`), for this call; a malformed item or an unknown run is refused by name."""
    for item in items:
        name, sep, weight = item.partition("=")
        if not sep or name not in runs:
            raise ValueError(f"{item!r}: expected RUN=W with RUN one of {', '.join(runs)}")
        try:
            value = float(weight)
        except ValueError:
            raise ValueError(f"{item!r}: the weight {weight!r} is not a number") from None
        runs = with_synth_weight(runs, name, value)
    return runs


def make_shards(out: Path, rendered: Path, workers: int, seconds: float, smoke: bool, names: list[str]
                ) -> dict[str, dict]:
    """Write (or continue) the shard folders that the runs `names` train on within `seconds` in all,
    each getting a share of the time left by its image count, so every run has shards to start from."""
    spec, ids = dataset_spec(rendered), garment_marker_ids(rendered)
    folders = [f for f in SHARDS if any(RUNS[name][4] == f and RUNS[name][1] > 0 for name in names)]
    counts = [SHARDS[f][1] for f in folders]
    started, results = time.perf_counter(), {}
    for k, folder in enumerate(folders):
        task, count = SHARDS[folder][:2]
        left = seconds - (time.perf_counter() - started)
        results[folder] = write_shards(out / "shards" / folder, task, spec, 4 if smoke else count, shard_config(folder),
                                       ids, workers, images_per_part=4 if smoke else 64,
                                       time_limit_s=max(left * count / sum(counts[k:]), 0.0), progress=False)
    return results


def synth_heldout(out: Path, rendered: Path, workers: int, smoke: bool, names: list[str]) -> dict[str, Path]:
    """Per shard folder that a run of `names` trains on, a small one of the same synthesizer config
    from another seed (`SYNTH_HELDOUT`; the training shards use SynthConfig's): samples no run saw, on
    which `evaluate_synthesized` measures the runs beside the renders."""
    spec, ids = dataset_spec(rendered), garment_marker_ids(rendered)
    images, seed = SYNTH_HELDOUT
    folders = {}
    for folder in dict.fromkeys(RUNS[name][4] for name in names if RUNS[name][1] > 0):
        folders[folder] = out / "shards_heldout" / folder
        write_shards(folders[folder], SHARDS[folder][0], spec, 2 if smoke else images, shard_config(folder, seed),
                     ids, workers, images_per_part=2 if smoke else 8, progress=False)
    return folders


def shard_config(folder: str, seed: int | None = None) -> SynthConfig:
    """The synthesizer config of shard folder `folder` (`SHARDS`, `SHARD_SYNTH`); `seed`: another seed
    than SynthConfig's (held-out samples)."""
    _, _, jitter, partial = SHARDS[folder]
    return SynthConfig(image_size=(IMAGE_SIZE, IMAGE_SIZE), crop_jitter_px=jitter, recognizer_partial=partial,
                       **SHARD_SYNTH.get(folder, {}), **({} if seed is None else {"seed": seed}))


def evaluate_synthesized(out: Path, folders: dict[str, Path], device: str, init: dict[str, str] | None = None
                         ) -> dict[str, dict]:
    """Each trained run's last.pt, and each checkpoint a run started from (--init), on the held-out
    synthesized samples of its shard folder (`synth_heldout`)."""
    checkpoints = {name: (name, out / name / "run" / "last.pt") for name in RUNS
                   if (out / name / "run" / "last.pt").exists()}
    for name, path in (init or {}).items():
        checkpoints[f"{name}, its --init"] = (name, Path(path))
    return {label: evaluate(path, folders[RUNS[name][4]], device=device, progress=False)
            for label, (name, path) in checkpoints.items() if RUNS[name][4] in folders}


def placement(active: list[str], gpus: int) -> dict[str, list[int]]:
    """The GPUs of each active run: the main runs first, heaviest first (`GPU_COST`), then the other
    runs, each on the GPU with the least cost placed so far (so on two GPUs the crosspoint run has
    one to itself and the two lighter runs share the other, and a comparison run beside the three
    main runs on four GPUs has the fourth to itself); GPUs left over join the heaviest main runs
    (`HEAVIEST`) as further DDP ranks.  No GPUs (the CPU): every run gets [] (one process)."""
    if gpus < 1:
        return {name: [] for name in active}
    load, placed = [0.0] * gpus, {}
    mains = [MAIN[task] for task in HEAVIEST if MAIN[task] in active]
    for name in mains + [n for n in active if n not in mains]:
        gpu = min(range(gpus), key=lambda g: (load[g], g))
        placed[name], load[gpu] = [gpu], load[gpu] + GPU_COST[RUNS[name][0]]
    spare = [g for g in range(gpus) if load[g] == 0.0]
    for k, gpu in enumerate(spare if mains else []):
        placed[mains[k % len(mains)]].append(gpu)
    return {name: placed[name] for name in active}


def sharing_note(placed: dict[str, list[int]]) -> str:
    """A line for the log when runs of `placement` share a GPU ("" when none do): the runs are fed by
    the CPU's data workers, and five runs on four GPUs each trained 30-40% slower than four runs did,
    the ones with a GPU of their own included."""
    shared: dict[int, list[str]] = {}
    for name, gpus in placed.items():
        if gpus:  # a run's first GPU (its other ranks' GPUs are its own)
            shared.setdefault(gpus[0], []).append(name)
    pairs = [f"GPU {gpu}: {', '.join(names)}" for gpu, names in sorted(shared.items()) if len(names) > 1]
    if not pairs:
        return ""
    return (f"note: {len(placed)} runs on {len(shared)} GPUs share them ({'; '.join(pairs)}); every run gets "
            "fewer data workers and trains slower (five runs on four GPUs: 30-40% slower than four on four)")


def worker_counts(active: list[str], ranks: dict[str, int], cores: int, smoke: bool) -> dict[str, int]:
    """Data workers per rank of each active run: the cores left to the runs' own processes (one per
    rank), by the runs' shares, split among a run's ranks."""
    if smoke:
        return {name: 0 for name in active}
    processes = sum(ranks[name] for name in active)
    spare = max(processes, cores - processes)
    total = sum(RUNS[name][3] for name in active)
    return {name: max(1, int(RUNS[name][3] * spare / total / ranks[name] + 0.5)) for name in active}


def pretrained_weights(folder: Path | None) -> dict[str, str]:
    """Per task, a torchvision ImageNet ResNet file in `folder` (torchvision's cache names it
    resnet18-<hash>.pth and resnet50-<hash>.pth): ResNet-18 for the localizer, ResNet-50 for the others;
    tasks without one are left out."""
    if folder is None or not folder.is_dir():
        return {}
    found = {depth: sorted(folder.glob(f"resnet{depth}-*.pth")) for depth in (18, 50)}
    return {task: str(found[depth][0].resolve()) for task, depth in
            (("localizer", 18), ("recognizer", 50), ("crosspoints", 50)) if found[depth]}


def init_weights(folder: Path | None, runs: list[str] | None = None) -> dict[str, str]:
    """Per run name (of `runs`, default all), the checkpoint in `folder` that the new run starts from
    (`networks.train --init`): `<run>.pt` (a slim one from an earlier `--export-weights`), else its
    task's `<task>.pt` (the repository's stored weights, `python -m networks.weights fetch`); runs with
    neither are left out."""
    if folder is None or not folder.is_dir():
        return {}
    found = {}
    for name, (task, *_) in RUNS.items():
        if runs is not None and name not in runs:
            continue
        path = next((p for p in (folder / f"{name}.pt", folder / f"{task}.pt") if p.is_file()), None)
        if path is not None:
            found[name] = str(path.resolve())
    return found


def main_checkpoints(out: Path, init: dict[str, str] | None = None) -> list[Path] | None:
    """The localizer's, recognizer's and crosspoint network's checkpoints that the Detector chains: each
    main run's last.pt, or, for a main run not trained in `out`, the checkpoint it would have started
    from (`--init`); None when a task has neither."""
    paths = []
    for task in ("localizer", "recognizer", "crosspoints"):
        last = out / MAIN[task] / "run" / "last.pt"
        start = (init or {}).get(MAIN[task])
        if not last.exists() and start is None:
            return None
        paths.append(last if last.exists() else Path(start))
    return paths


def run_config(name: str, workers: int, max_steps: int | None, pretrained: dict[str, str],
               init: dict[str, str] | None = None, init_lr: float | None = None) -> TrainConfig:
    """The `networks.train` config of run `name`: from `init`'s checkpoint of it at peak `init_lr`
    (default: LR), else from `pretrained` (or scratch) at LR."""
    task, synth_weight, _, _, folder = RUNS[name]
    start = (init or {}).get(name)
    lr = init_lr if start and init_lr is not None else LR
    steps, batch = SCHEDULE[task]
    if max_steps:  # smoke runs: a few steps of tiny batches
        steps, batch = min(steps, max_steps), 2
    return TrainConfig(task=task, steps=steps, batch_size=batch, image_size=IMAGE_SIZE, lr=lr, warmup_steps=WARMUP,
                       pretrained=None if start else pretrained.get(task), init=start,
                       crop_jitter_px=SHARDS[folder][2] if task != "localizer" else 0.0,
                       recognizer_partial=SHARDS[folder][3],
                       num_workers=workers, val_every=min(VAL_EVERY[task], steps), val_samples=8 if max_steps else 512,
                       checkpoint_every=CHECKPOINT_EVERY, log_every=50, synth_weight=synth_weight)


def train_all(out: Path, rendered: Path, device: str, cores: int, seconds: float, max_steps: int | None,
              names: list[str], final: bool = False, ddp: bool = False, pretrained: dict[str, str] | None = None,
              init: dict[str, str] | None = None, init_lr: float | None = None) -> dict[str, dict]:
    """Start (or continue) every unfinished run of `names`, all at once on the GPUs (`placement`; one
    after another on the CPU), each for at most `seconds`; `final`: the main runs fit their schedules
    to end within this call (`--fit-time-limit`).  Returns per run its steps, planned steps, wall time
    and logged losses."""
    smoke = max_steps is not None
    targets = {name: min(RUNS[name][2] or SCHEDULE[RUNS[name][0]][0], max_steps or 10**9) for name in names}
    before = {name: run_step(out / name / "run") for name in names}
    active = [name for name in names if before[name] < targets[name]]
    fitted = {name for name in active if final and RUNS[name][2] is None}  # the runs without a fixed stop
    gpus = placement(active, torch.cuda.device_count() if device.startswith("cuda") and not smoke else 0)
    if not ddp:  # one GPU per run, spare GPUs idle (DDP ranks slow a run down; see the docstring)
        gpus = {name: g[:1] for name, g in gpus.items()}
    if note := sharing_note(gpus):
        print(note, flush=True)
    ranks = {name: max(1, len(gpus[name])) for name in active}
    workers = worker_counts(active, ranks, cores, smoke)
    deadline = time.monotonic() + seconds + START_S
    results, processes = {}, {}

    def launch(name: str) -> None:
        task = RUNS[name][0]
        folder = out / name
        folder.mkdir(parents=True, exist_ok=True)
        run_config(name, workers[name], max_steps, pretrained or {}, init, init_lr).save(folder / "config.in.json")
        launcher = [sys.executable]
        if ranks[name] > 1:  # DDP: one process per GPU (`networks.distributed`)
            launcher += ["-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(ranks[name])]
        command = [*launcher, "-m", "networks.train", task, "--data", str(rendered), "--out", str(folder / "run"),
                   "--config", str(folder / "config.in.json"), "--device", device, "--resume", "--no-progress",
                   "--workers", str(workers[name]), "--until-step", str(targets[name]),
                   "--time-limit", str(max(1.0, deadline - START_S - time.monotonic()))]
        if name in fitted:
            command += ["--fit-time-limit"]
        if RUNS[name][1] > 0:
            command += ["--shards", str(out / "shards" / RUNS[name][4])]
        log = open(folder / "train.log", "a")
        # on a GPU the runs' own processes only feed it: two OpenMP threads each, the cores go to the workers
        env = dict(os.environ, **({} if smoke else {"OMP_NUM_THREADS": "2", "MKL_NUM_THREADS": "2"}))
        if gpus[name]:
            env["CUDA_VISIBLE_DEVICES"] = ",".join(map(str, gpus[name]))
        processes[name] = (subprocess.Popen(command, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=env),
                           time.perf_counter(), log)

    def collect(name: str) -> None:
        process, started, log = processes.pop(name)
        try:
            status = process.wait(timeout=max(1.0, deadline + 30 - time.monotonic()))
        except subprocess.TimeoutExpired:  # past the budget: Ctrl-C writes last.pt and stops
            process.send_signal(signal.SIGINT)
            status = process.wait()
        log.close()
        text = (out / name / "train.log").read_text()
        if status != 0:  # recorded, and the other runs still count
            results[name] = {"error": f"exit status {status}: {text[-2000:]}"}
            return
        results[name] = {"seconds": time.perf_counter() - started, "summary": text.strip().splitlines()[-1],
                         "workers": workers[name], "gpus": gpus[name], "fitted": name in fitted}

    for name in active:
        launch(name)
        if smoke:
            collect(name)
    for name in list(processes):
        collect(name)
    for name in names:
        records = _log(out / name / "run")
        losses = [r for r in records if "loss" in r]
        startups = [r["startup"] for r in records if "startup" in r]
        fifty = [r["elapsed_s"] for r in losses if r["step"] == before[name] + 50]
        step = run_step(out / name / "run")
        entry = results.setdefault(name, {"seconds": 0.0, "summary": "already at its last step"})
        config = out / name / "run" / "config.json"
        planned = json.loads(config.read_text())["steps"] if config.exists() else None
        entry.update(step=step, target=min(targets[name], planned or targets[name]), planned_steps=planned,
                     steps_this_call=step - before[name],
                     first_loss=losses[0]["loss"] if losses else None, last_loss=losses[-1]["loss"] if losses else None,
                     startup={**(startups[-1] if startups else {}), **({"step_50_s": fifty[-1]} if fifty else {})})
        if entry.get("seconds"):
            entry["steps_per_s"] = entry["steps_this_call"] / entry["seconds"]
    return results


def _log(run: Path) -> list[dict]:
    path = run / "log.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line] if path.exists() else []


def compare_mixes(out: Path) -> dict[str, dict]:
    """The localizer runs' validation (rendered val split) at the last step all of them logged."""
    logs = {name: {r["step"]: r["val"] for r in _log(out / name / "run") if "val" in r}
            for name, (task, *_) in RUNS.items() if task == "localizer"}
    common = set.intersection(*(set(v) for v in logs.values())) if all(logs.values()) else set()
    if not common:
        return {}
    step = max(common)
    return {name: {"step": step, **val[step]} for name, val in logs.items()}


def evaluate_runs(out: Path, test: Path, device: str) -> dict[str, dict]:
    """Each run's last.pt on the held-out renders (kept from an earlier call when the step is unchanged)."""
    metrics = {}
    for name in RUNS:
        last, cached = out / name / "run" / "last.pt", out / name / "heldout.json"
        if not last.exists():
            continue
        step = run_step(out / name / "run")
        if cached.exists() and json.loads(cached.read_text()).get("step") == step:
            metrics[name] = json.loads(cached.read_text())
            continue
        metrics[name] = evaluate(last, test, split="heldout", device=device, progress=False)
        save_json(cached, metrics[name])
    return metrics


def evaluate_compact(out: Path, test: Path, device: str) -> dict[str, dict]:
    """Each main run's last.pt as a compact int8 checkpoint in `out`/compact/<task>.pt (the form
    `networks.weights store` keeps, named as it wants them), evaluated on the held-out renders beside
    the float weights' "metrics": what the rounding costs.  Per task: the run, the file's bytes, the
    metrics."""
    metrics = {}
    for task, name in MAIN.items():
        last = out / name / "run" / "last.pt"
        if last.exists():
            compact = slim_checkpoint(last, out / "compact" / f"{task}.pt", dtype=torch.int8)
            metrics[task] = {"run": name, "bytes": compact.stat().st_size,
                             **evaluate(compact, test, split="heldout", device=device, progress=False)}
    return metrics


def evaluate_inits(init: dict[str, str], test: Path, device: str) -> dict[str, dict]:
    """Each checkpoint a run started from (`--init`) on the same held-out renders: the baseline of
    this call's training, measured beside it (a checkpoint that several runs start from, once)."""
    metrics: dict[str, dict] = {}
    for path in dict.fromkeys(init.values()):
        metrics[path] = evaluate(path, test, split="heldout", device=device, progress=False)
    return {name: metrics[path] for name, path in init.items()}


def evaluate_chain(out: Path, test: Path, device: str, smoke: bool = False, init: dict[str, str] | None = None,
                   variants: bool = True, **config: object) -> dict[str, dict]:
    """`networks.evaluate_detector` of the three main runs chained (`main_checkpoints`), on the held-out
    renders, with the
    garment's tables: the defaults; without the neighbours' ID votes (`DetectorConfig.vote_ids`, the
    baseline of that step); without crosspoint smoothing (`DetectorConfig.smooth_crosspoints_px`, the
    network's raw outputs); with the cut threshold (`max_layout_residual_cells`) at the 1 cell it was
    before; and with the comparison runs on exact crops in place of the main runs, where they exist;
    keyed by a label of the variant (`variants` False: the defaults alone); `config`: DetectorConfig
    fields set in every variant."""
    paths = main_checkpoints(out, init)
    chains = {"defaults": (paths, {})}
    if variants:
        chains.update({"no ID votes": (paths, {"vote_ids": False}),
                       "no crosspoint smoothing": (paths, {"smooth_crosspoints_px": None}),
                       "cut above 1 cell": (paths, {"max_layout_residual_cells": 1.0})})
        exact = [out / name / "run" / "last.pt" for name in ("recognizer", "crosspoints")]
        if exact[0].exists():
            chains["recognizer on exact crops"] = ([paths[0], exact[0], paths[2]], {})
        if exact[1].exists():
            chains["crosspoints on exact crops"] = ([paths[0], paths[1], exact[1]], {})
        if exact[0].exists() and exact[1].exists():
            chains["both on exact crops"] = ([paths[0], *exact], {})
    return {label: chain_metrics(checkpoints, test, device, smoke, **config, **overrides)
            for label, (checkpoints, overrides) in chains.items()}


def chain_metrics(checkpoints: list[Path], view: Path, device: str, smoke: bool = False, **config: object) -> dict:
    """`networks.evaluate_detector` of a Detector chaining `checkpoints` (localizer, recognizer, crosspoints)
    with `config` (DetectorConfig fields; smoke runs: `SMOKE_DETECTOR`) on the held-out split of `view`."""
    from networks.detector import DetectorConfig
    from networks.evaluate_detector import evaluate_detector, load_detector

    detector = load_detector(*checkpoints, view, device=device,
                             config=DetectorConfig(**(SMOKE_DETECTOR if smoke else {}), **config))
    return evaluate_detector(detector, view, split="heldout", progress=False)


#: the presence threshold of the Detector's defaults and the reference's (`DetectorConfig.presence_threshold`)
REFERENCE_THRESHOLD = 0.5
#: the presence thresholds swept by default (`thresholds_arg` adds the reference)
DEFAULT_THRESHOLDS = "0.2,0.3,0.35,0.4,0.45,0.5"


def thresholds_arg(text: str) -> list[float]:
    """'0.2,0.3,0.5' -> sorted distinct thresholds in (0, 1); the reference's 0.5 is always among them."""
    try:
        values = {float(item) for item in text.split(",") if item.strip()}
    except ValueError:
        raise argparse.ArgumentTypeError(f"--thresholds: {text!r} is not a comma-separated list of numbers")
    outside = sorted(v for v in values if not 0 < v < 1)
    if outside:
        raise argparse.ArgumentTypeError(f"--thresholds: {outside} are not in (0, 1)")
    return sorted(values | {REFERENCE_THRESHOLD})


def choose_threshold(metrics: dict[float, dict]) -> float:
    """The threshold whose fully visible markers' F1 is highest in `metrics` (threshold -> the
    localizer's `networks.evaluate` metrics); of equal F1, the highest threshold (the nearer the
    reference)."""
    if not metrics:
        raise ValueError("no thresholds were evaluated")
    return max(metrics, key=lambda t: (round(metrics[t]["full"]["f1"], 9), t))


def sweep(checkpoint: Path, data: Path, thresholds: list[float], choose_split: str = "val",
          test_split: str = "test", device: str = "cpu") -> dict:
    """The localizer `checkpoint` on `data`'s `choose_split` at each of `thresholds` (`networks.evaluate`,
    the localizer run once per split and decoded at every threshold), the threshold chosen there
    (`choose_threshold`: reading the best threshold off the test split itself would prove nothing),
    and that one and the reference's on `test_split`:
    {"chosen", "choose_split", "test_split", "choose": {t: metrics}, "test": {t: metrics}}."""
    if choose_split == test_split:
        raise ValueError("the threshold must be chosen on another split than the one it is tested on: a "
                         "threshold read off its test split proves nothing")

    def measure(split: str, wanted: list[float]) -> dict[float, dict]:  # one localizer pass per split
        metrics = evaluate_at(checkpoint, data, wanted, split=split, task="localizer", device=device, progress=False)
        full = metrics[wanted[0]]["full"]
        if full["true_positive"] + full["false_negative"] == 0:
            raise ValueError(f"{data}: the split {split!r} has no fully visible markers")
        return metrics

    chosen_metrics = measure(choose_split, sorted(set(thresholds) | {REFERENCE_THRESHOLD}))
    chosen = choose_threshold(chosen_metrics)
    return {"chosen": chosen, "choose_split": choose_split, "test_split": test_split, "choose": chosen_metrics,
            "test": measure(test_split, sorted({chosen, REFERENCE_THRESHOLD}))}


def evaluate_threshold(out: Path, rendered: Path, device: str, init: dict[str, str] | None = None) -> dict:
    """The main localizer's presence threshold chosen by F1 on the rendered dataset's val split and
    checked beside the reference's 0.5 on its test split (`sweep`): the compact
    checkpoint that would be stored, else the main run's last.pt, else its --init; {} without one, or
    when the dataset lacks either split.  A localizer whose presence probability is conservative finds
    more markers at a lower threshold: one met 0.99 P/R on fully visible test markers at 0.35 (chosen
    on val)."""
    compact = out / "compact" / "localizer.pt"
    checkpoints = main_checkpoints(out, init)
    localizer = compact if compact.exists() else checkpoints[0] if checkpoints else None
    splits = {entry["split"] for entry in read_manifest(rendered)}
    if localizer is None or not {"val", "test"} <= splits:  # nothing to sweep, or no split to choose on
        return {}
    return {"checkpoint": str(localizer),
            **sweep(localizer, rendered, thresholds_arg(DEFAULT_THRESHOLDS), "val", "test", device)}


def evaluate_partial_ids(out: Path, test: Path, device: str, init: dict[str, str] | None = None
                         ) -> dict[str, dict]:
    """The recognizers' top-1 given the true five points on the held-out renders, whole against partial
    markers, by marker size, and whole markers by the share of their crosspoints visible and by layout
    residual (`networks.recognizer_top1.top1`: {"groups", "by_size", "by_visible", "by_residual"}): every
    recognizer run's last.pt, and the checkpoint the main one started from (`--init`), so a run's change
    shows beside its start in the same call.  The size shows where the errors are: one recognizer read
    0.996 of the fully visible markers of 16-24 px and 0.78 of those under 12 px."""
    from networks.evaluate_detector import load_detector  # the garment's tables without assets.garments (triangle)
    from networks.recognizer_top1 import rendered_pairs, top1

    localizer, _, crosspoints = main_checkpoints(out, init)
    recognizers = {f"{name} (step {run_step(out / name / 'run')})": out / name / "run" / "last.pt"
                   for name, (task, *_) in RUNS.items()
                   if task == "recognizer" and (out / name / "run" / "last.pt").exists()}
    if (init or {}).get(MAIN["recognizer"]):
        recognizers[f"{MAIN['recognizer']}, its --init"] = Path(init[MAIN["recognizer"]])
    pairs = rendered_pairs(test)
    results = {}
    for label, path in recognizers.items():
        results[label] = top1(load_detector(localizer, path, crosspoints, test, device=device), pairs)
    return results


def evaluate_extra(out: Path, view: Path, device: str, init: dict[str, str] | None = None, smoke: bool = False
                   ) -> dict:
    """The Detector's networks (`main_checkpoints`) on a second folder of held-out renders
    (`--extra-heldout`, every image held out; made, say, at another resolution or of unseen motions):
    each network's `networks.evaluate` metrics, the chain with its defaults, and the recognizer's top-1
    given the true points by group and marker size (`networks.recognizer_top1.top1`).  The chain runs
    three times: with the localizer at full size, at 512 / the image side (the scale of the renders it
    trained on, as in `throughput`), and at the scale it chooses per image (`DetectorConfig.localizer_scale`
    None)."""
    from networks.evaluate_detector import load_detector
    from networks.recognizer_top1 import rendered_pairs, top1

    paths = main_checkpoints(out, init)
    metrics = {task: evaluate(path, view, split="heldout", device=device, progress=False)
               for task, path in zip(("localizer", "recognizer", "crosspoints"), paths)}
    pairs = rendered_pairs(view)
    recognizer_top1 = top1(load_detector(*paths, view, device=device), pairs)
    side = max(cv2.imread(str(pairs[0][0]), cv2.IMREAD_UNCHANGED).shape[:2])
    chains = {}
    for scale in [*sorted({1.0, min(1.0, 512 / side)}, reverse=True), None]:
        chain = evaluate_chain(out, view, device, smoke, init, variants=False, localizer_scale=scale)["defaults"]
        chosen = chain["localizer_scale"]
        label = f"{scale:.2g}" if scale is not None else f"auto ({chosen['min']:.2f}-{chosen['max']:.2f})"
        chains[f"localizer scale {label}"] = chain
    return {"images": len(pairs), "checkpoints": [str(p) for p in paths], "metrics": metrics,
            "detector": chains, "recognizer_top1": recognizer_top1}


def throughput(out: Path, device: str, sizes: tuple[int, ...], repeats: int, smoke: bool = False,
               init: dict[str, str] | None = None) -> list[dict]:
    """Detector images per second on `repeats` synthesized images of each size, framed as the renders
    (marker size grows with the image side; the localizer sees the image at 512 / side, the scale it
    was trained on), after a warm-up call on the first and with every ID's reference texture rendered;
    with the stage times (`networks.detector.DetectorResult.stage_seconds`) and the markers found on the
    first image (the same on every device) and the markers the images show (smoke runs:
    `SMOKE_DETECTOR`).  Each size is timed with the Detector's defaults and with each of
    `THROUGHPUT_VARIANTS`, on the same images: the baseline a slower default shows against."""
    from networks import Detector, DetectorConfig

    paths = main_checkpoints(out, init)
    rows = []
    for size in sizes:
        scale = min(1.0, 512 / size)
        marker = tuple(v * size / 512 for v in SynthConfig().marker_px)
        detectors = {variant: Detector.from_checkpoints(*paths, device=device, config=DetectorConfig(
                         **(SMOKE_DETECTOR if smoke else {}), localizer_scale=scale, **overrides))
                     for variant, overrides in {"defaults": {}, **THROUGHPUT_VARIANTS}.items()}
        synth = PatternSynthesizer(detectors["defaults"].spec, SynthConfig(image_size=(size, size), marker_px=marker, seed=7))
        samples = [synth.sample(i) for i in range(repeats)]  # the same images for every variant
        images = [image for image, *_ in samples]
        shown = [int((gt.status > 0).sum()) for _, gt, *_ in samples]
        for variant, detector in detectors.items():
            rows.append({"variant": variant, **_time_detector(detector, images, device),
                         "size": size, "localizer_scale": scale, "shown_per_image": float(np.mean(shown)),
                         "shown_first_image": shown[0]})
    return rows


def _time_detector(detector, images: list[np.ndarray], device: str) -> dict:
    """One Detector's images per second on `images`, after every ID's reference texture was rendered
    (a garment's Detector renders its IDs when built) and a warm-up call (CUDA kernels, cuDNN's
    algorithm choice: the first image on a GPU, a corner on a CPU)."""
    detector.references(np.arange(len(detector.codebook)))
    detector([images[0] if device.startswith("cuda") else np.ascontiguousarray(images[0][:256, :256])])
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    start = time.perf_counter()
    result = detector.detect(images)
    found = [len(d) for d in result.detections]
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    seconds = time.perf_counter() - start
    return {"device": device, "precision": "float32", "images": len(images), "seconds": seconds,
            "images_per_s": len(images) / seconds, "markers_per_image": float(np.mean(found)),
            "stage_seconds": result.stage_seconds,
            "found_first_image": found[0]}


def main() -> None:
    started = time.monotonic()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rendered", type=Path, required=True, help="a factory dataset folder (Blender renders)")
    parser.add_argument("--out", type=Path, default=Path("out/bench_networks"),
                        help="shards, runs and results; the same folder again continues the runs")
    parser.add_argument("--budget-minutes", type=float, default=9.0, help="wall time of this call, all included")
    parser.add_argument("--shard-minutes", type=float, default=2.5, help="at most this long writing shards per call")
    parser.add_argument("--cores", type=int, default=os.cpu_count() or 2, help="CPU cores to size the workers to")
    parser.add_argument("--device", default="cuda", help="cpu: a smoke run of this script (with --max-steps)")
    parser.add_argument("--max-steps", type=int, help="cap every run's steps (smoke runs)")
    parser.add_argument("--eval-images", type=int, help="evaluate on the first N rendered images only (smoke runs)")
    parser.add_argument("--sizes", default="1024,2048", help="image sides for the GPU throughput")
    parser.add_argument("--cpu-sizes", default="1024,2048", help="image sides for the CPU throughput ('' for none)")
    parser.add_argument("--codebook-hash", help="the rendering machine's codebook hash; stop if this one differs")
    parser.add_argument("--runs", default=",".join(MAIN.values()),
                        help=f"runs to train this call (of {', '.join(RUNS)}; default the main runs)")
    parser.add_argument("--final", action="store_true", help="the last call: each main run fits its schedule "
                        "to end within this call (at the step rate measured early in it, then again)")
    parser.add_argument("--ddp", action="store_true", help="spare GPUs join the heaviest main runs as DDP ranks "
                        "(default: one GPU per run, spare GPUs idle; two ranks trained the crosspoint network at "
                        "half the step rate of one GPU)")
    parser.add_argument("--pretrained", type=Path, help="a folder of torchvision ImageNet ResNet files "
                        "(resnet18-*.pth, resnet50-*.pth) to start new runs from; default: from scratch")
    parser.add_argument("--localizer-synth-weight", type=float,
                        help=f"the main localizer run's share of synthesized images (default "
                        f"{RUNS[MAIN['localizer']][1]}); 0 with --init: a last phase on the renders alone")
    parser.add_argument("--synth-weight", action="append", default=[], metavar="RUN=W",
                        help="run RUN's share of synthesized samples for this call (repeatable; 0: renders alone), "
                        "e.g. crosspoints_jitter=0")
    parser.add_argument("--init-lr", type=float, help="peak learning rate of the runs that start from --init "
                        f"(default {LR:g}, as from scratch)")
    parser.add_argument("--init", type=Path, help="a folder of slim checkpoints <run>.pt (an earlier call's "
                        "--export-weights) or <task>.pt (networks.weights fetch) that new runs start from "
                        "(networks.train --init)")
    parser.add_argument("--export-weights", action="store_true", help="also write each trained run as a compact "
                        "int8 checkpoint to <export>/store: <task>.pt for the main runs (networks.weights store), "
                        "<run>.pt for the others (--init elsewhere)")
    parser.add_argument("--export", type=Path, help="copy results.json and logs.tar.gz of the runs here ($OUT)")
    parser.add_argument("--extra-heldout", type=Path, help="a second factory dataset folder whose every image is "
                        "held out (other resolutions, unseen motions): the Detector's networks evaluated on it too")
    args = parser.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        sys.exit("benchmarks/train_networks.py trains on a CUDA GPU; none is visible")
    smoke = args.max_steps is not None
    if args.init_lr is not None and not args.init_lr > 0:
        sys.exit(f"--init-lr must be > 0, got {args.init_lr}")
    names = [n for n in args.runs.split(",") if n]
    unknown = sorted(set(names) - set(RUNS))
    if unknown:
        sys.exit(f"--runs: unknown run(s) {', '.join(unknown)}; the runs are {', '.join(RUNS)}")
    # this call's run table: shards, configs and results follow it (--localizer-synth-weight W is
    # --synth-weight localizer_mix=W)
    weights = args.synth_weight + ([] if args.localizer_synth_weight is None else
                                   [f"{MAIN['localizer']}={args.localizer_synth_weight}"])
    try:
        RUNS.update(synth_weights(weights, RUNS))
    except ValueError as exc:
        sys.exit(f"--synth-weight / --localizer-synth-weight {exc}")
    deadline = started + args.budget_minutes * 60
    args.out.mkdir(parents=True, exist_ok=True)
    spec = dataset_spec(args.rendered)
    here = codebook_hash(spec)
    if args.codebook_hash and here != args.codebook_hash:
        sys.exit(f"codebook differs from the rendering machine's ({here} vs {args.codebook_hash}): the rendered "
                 "IDs would not be this machine's IDs")
    rendered, rebuilt = prepare(args.rendered, args.out, 1 if smoke else args.cores)
    test = heldout(rendered, args.out, args.eval_images, markers=8 if smoke else None)
    if args.extra_heldout is not None:
        if codebook_hash(dataset_spec(args.extra_heldout)) != here:
            sys.exit(f"--extra-heldout {args.extra_heldout}: its pattern differs from --rendered's")
        extra, _ = prepare(args.extra_heldout, args.out, 1 if smoke else args.cores, name="extra")
        extra = heldout(extra, args.out, args.eval_images, markers=8 if smoke else None, every_split=True,
                        name="heldout_extra")
    shards = make_shards(args.out, rendered, max(1, args.cores - 1) if not smoke else 1,
                         min(args.shard_minutes * 60, deadline - time.monotonic() - RESERVE_S - START_S - 60), smoke,
                         names)
    synthesized = synth_heldout(args.out, rendered, max(1, args.cores - 1) if not smoke else 1, smoke, names)
    t0 = time.perf_counter()
    pretrained = pretrained_weights(args.pretrained)
    # the runs of this call, and the main runs a Detector chains from their start when not trained here
    init = init_weights(args.init, names + list(MAIN.values()))
    training = train_all(args.out, rendered, args.device, args.cores,
                         deadline - time.monotonic() - RESERVE_S - START_S, args.max_steps, names, args.final,
                         args.ddp, pretrained, init, args.init_lr)
    train_s = time.perf_counter() - t0
    gpu = f"{torch.cuda.device_count()} x {torch.cuda.get_device_name()}" if torch.cuda.is_available() else "no GPU"
    result = {"date": time.strftime("%Y-%m-%d"), "machine": f"{platform.node()}, {gpu}, "
              f"{os.cpu_count()} CPUs, torch {torch.__version__}", "codebook_hash": here, "samples_rebuilt": rebuilt,
              "schedule": {t: {"steps": s, "batch": b, "image": IMAGE_SIZE, "lr": LR, "warmup": WARMUP,
                                  "init_lr": args.init_lr if args.init_lr is not None else LR}
                           for t, (s, b) in SCHEDULE.items()},
              "runs": {name: {"task": t, "synth_weight": w, "stop": s, "shards": f, "crop_jitter_px": SHARDS[f][2],
                              "recognizer_partial": SHARDS[f][3], "synth": SHARD_SYNTH.get(f, {})}
                       for name, (t, w, s, _, f) in RUNS.items()},
              "pretrained": pretrained, "init": init,
              "heldout_images": len((test / "manifest.jsonl").read_text().splitlines()), "shards": shards,
              "train_wall_s": train_s, "training": training, "mixes": {}, "metrics": {}, "detector": {},
              "init_metrics": {}, "compact": {}, "presence_threshold": {}, "synthesized": {}, "partial_ids": {}, "extra": {}, "throughput": [], "errors": {}}
    stage = Stages(result, args.out / "results.json", started)
    stage("metrics", evaluate_runs, args.out, test, args.device)
    stage("compact", evaluate_compact, args.out, test, args.device)
    stage("presence_threshold", evaluate_threshold, args.out, rendered, args.device, init)
    stage("mixes", compare_mixes, args.out)
    if init:
        stage("init_metrics", evaluate_inits, init, test, args.device)
    stage("synthesized", evaluate_synthesized, args.out, synthesized, args.device, init)
    if main_checkpoints(args.out, init) is not None:  # a main run not trained here is chained from its --init
        stage("detector", evaluate_chain, args.out, test, args.device, smoke, init)
        stage("partial_ids", evaluate_partial_ids, args.out, test, args.device, init)
        if args.extra_heldout is not None:
            stage("extra", evaluate_extra, args.out, extra, args.device, init, smoke)
        sizes = [int(v) for v in args.sizes.split(",") if v] if not smoke else [256]
        stage("throughput", throughput, args.out, args.device, tuple(sizes),
              4 if args.device.startswith("cuda") else 1, smoke, init)
        cpu_sizes = [int(v) for v in args.cpu_sizes.split(",") if v]
        if args.device.startswith("cuda") and cpu_sizes and deadline - time.monotonic() > 45:
            stage("throughput", lambda: result["throughput"] + throughput(args.out, "cpu", tuple(cpu_sizes), 1,
                                                                          init=init))
    if args.export is not None:
        export(args.out, args.export, args.export_weights)
    for name, error in result["errors"].items():
        print(f"stage {name} failed (the others ran; results.json has the traceback):\n{error}", file=sys.stderr)
    _print_tables(result)
    print("RESULT " + json.dumps(result, default=float))
    if result["errors"]:
        sys.exit(f"{len(result['errors'])} stage(s) failed: {', '.join(result['errors'])}")


class Stages:
    """The evaluation stages after training, each kept apart: `stage(key, fn, *args)` stores fn's
    value as result[key], or, when it raises, its traceback in result["errors"][key] and goes on;
    results.json is written after every stage, so a late failure loses nothing done before it (such
    as the shard and run tables)."""

    def __init__(self, result: dict, path: Path, started: float) -> None:
        self.result, self.path, self.started = result, path, started
        result["wall_s"] = time.monotonic() - started
        save_json(path, result)

    def __call__(self, key: str, fn, *args) -> None:
        try:
            self.result[key] = fn(*args)
        except Exception:  # noqa: BLE001 - any failure of one stage is recorded, the next still runs
            self.result["errors"][key] = traceback.format_exc()
        self.result["wall_s"] = time.monotonic() - self.started
        save_json(self.path, self.result)


def export(out: Path, to: Path, weights: bool = False) -> None:
    """Copy results.json to `to`, with logs.tar.gz of each run's config, log.jsonl, train.log and
    held-out metrics (two files: the device machine returns few); `weights`: every trained run as a
    compact int8 checkpoint in `to`/store: the main runs' (`evaluate_compact`) as <task>.pt, for
    `networks.weights store`, the others' last.pt as <run>.pt (`networks.checkpoint.slim_checkpoint`),
    for `--init`."""
    to.mkdir(parents=True, exist_ok=True)
    if weights:
        (to / "store").mkdir(parents=True, exist_ok=True)
        for compact in sorted((out / "compact").glob("*.pt")):
            shutil.copy2(compact, to / "store" / compact.name)
        for name in RUNS:
            if name not in MAIN.values() and (out / name / "run" / "last.pt").exists():
                slim_checkpoint(out / name / "run" / "last.pt", to / "store" / f"{name}.pt", dtype=torch.int8)
    shutil.copy2(out / "results.json", to / "results.json")
    with tarfile.open(to / "logs.tar.gz", "w:gz") as tar:
        for name in RUNS:
            for path in (out / name / "train.log", out / name / "heldout.json", out / name / "run" / "log.jsonl",
                         out / name / "run" / "config.json"):
                if path.exists():
                    tar.add(path, arcname=f"{name}/{path.name}")


def _print_tables(result: dict) -> None:
    print(f"# networks benchmark, {result['date']}, {result['machine']}, {result['wall_s']:.0f} s")
    print("\n| shards | parts | items | written images | s | images/s | per worker | worker ms per image "
          "(start excluded) | first part after s | workers busy |\n|---|---|---|---|---|---|---|---|---|---|")
    for task, r in result["shards"].items():
        in_worker = "-" if r.get("worker_seconds_per_image") is None else f"{1e3 * r['worker_seconds_per_image']:.0f}"
        first = "-" if r.get("first_part_s") is None else f"{r['first_part_s']:.1f}"
        print(f"| {task} | {r['parts']} | {r['items']} | {r['written_images']} | {r['seconds']:.0f} | "
              f"{r['images_per_s']:.1f} | {r['images_per_s_per_worker']:.1f} | {in_worker} | {first} | "
              f"{r.get('busy', 0.0):.0%} |")
    print("\n| run | synth weight | GPUs | workers per rank | step / target | this call: steps, s, steps/s "
          "| start-up s: setup, first batch, first step, step 50 | loss first -> last |")
    print("|---|---|---|---|---|---|---|---|")
    weights = {name: run["synth_weight"] for name, run in result["runs"].items()}  # this call's, not the defaults
    for name, r in result["training"].items():
        weight = weights[name]
        if "error" in r:
            print(f"| {name} | {weight} | | | failed: {r['error'][-300:]!r} | | | |")
            continue
        loss = "-" if r["first_loss"] is None else f"{r['first_loss']:.4g} -> {r['last_loss']:.4g}"
        gpus = ",".join(map(str, r.get("gpus") or [])) or "-"
        startup = r.get("startup") or {}
        start = ", ".join(_number(startup.get(k), ".1f") for k in ("setup_s", "first_batch_s", "first_step_s",
                                                                    "step_50_s"))
        print(f"| {name} | {weight} | {gpus} | {r.get('workers', '-')} | {r['step']} / {r['target']} | "
              f"{r['steps_this_call']}, {r['seconds']:.0f}, {r.get('steps_per_s', 0):.2f} | {start} | {loss} |")
    if result["mixes"]:
        print("\n| localizer data (rendered val split, same step) | step | loss | precision | recall | F1 "
              "| recall full | centre median px |\n|---|---|---|---|---|---|---|---|")
        for name, m in result["mixes"].items():
            a = m["all"]
            full = f"{m['full']['recall']:.3f}" if "full" in m else "-"
            print(f"| {name} ({weights[name]} synth) | {m['step']} | {m['loss']['total']:.4g} | {a['precision']:.3f} | "
                  f"{a['recall']:.3f} | {a['f1']:.3f} | {full} | {a['error_px']['centre']['median']:.2f} |")
    print(f"\n| metric ({result['heldout_images']} held-out Blender renders) | value |\n|---|---|")
    inits = {f"{name}, its --init": m for name, m in result.get("init_metrics", {}).items()}
    compact = {f"{m['run']}, int8": m for m in result.get("compact", {}).values()}
    _print_metrics({**result["metrics"], **inits, **compact})
    if result.get("synthesized"):
        print(f"\n| metric (held-out synthesized samples, {SYNTH_HELDOUT[0]} images per shard folder) | value |"
              "\n|---|---|")
        _print_metrics(result["synthesized"])
    if result["detector"]:
        _print_chains(f"{result['heldout_images']} held-out renders", result["detector"])
    if result.get("partial_ids"):
        _print_top1(f"{result['heldout_images']} held-out renders", result["partial_ids"])
    if result.get("presence_threshold"):
        print()
        print_sweep(result["presence_threshold"], f"# presence threshold of {result['presence_threshold']['checkpoint']}")
    if result.get("extra"):
        _print_extra(result["extra"])
    print("\n| device (float32) | image | Detector | localizer scale | images/s | markers found / shown per image "
          "| first image: found / shown | stages s/image: localize, recognize, vote, complete, crosspoints "
          "|\n|---|---|---|---|---|---|---|---|")
    for r in result["throughput"]:
        print(f"| {r['device']} | {r['size']} x {r['size']} | {r.get('variant', 'defaults')} | "
              f"{r.get('localizer_scale', 1.0):.2g} | "
              f"{r['images_per_s']:.3g} | {r['markers_per_image']:.0f} / {r.get('shown_per_image', 0):.0f} | "
              f"{r.get('found_first_image', '-')} / {r.get('shown_first_image', '-')} | {_stages(r, r['images'])} |")


def print_sweep(result: dict, title: str) -> None:
    """`sweep`'s two tables under `title`: every threshold on the choosing split, then the chosen one
    beside the reference on the test split."""
    chosen = float(result["chosen"])  # the keys are strings once the result went through JSON
    header = ("| threshold | fully visible P / R / F1 | all markers P / R | predictions on partial markers | "
              "median px centre, TL, TR, BL, BR |\n|---|---|---|---|---|")

    def row(threshold: float, metrics: dict) -> str:
        full, every = metrics["full"], metrics["all"]
        mark = " (chosen)" if threshold == chosen else " (reference)" if threshold == REFERENCE_THRESHOLD else ""
        corners = ", ".join(f"{full['error_px'][p]['median']:.2f}" for p in ("centre", "TL", "TR", "BL", "BR"))
        return (f"| {threshold:g}{mark} | {full['precision']:.4f} / {full['recall']:.4f} / {full['f1']:.4f} | "
                f"{every['precision']:.4f} / {every['recall']:.4f} | {full.get('on_other_markers', 0)} | {corners} |")

    print(f"{title}\n\n## chosen on {result['choose_split']!r} (best F1 on fully visible markers: {chosen:g})\n"
          f"{header}")
    for t, m in result["choose"].items():
        print(row(float(t), m))
    print(f"\n## checked on {result['test_split']!r}, beside the reference\n{header}")
    for t, m in result["test"].items():
        print(row(float(t), m))


def _print_metrics(metrics: dict[str, dict]) -> None:
    """One table row per number of each label's `networks.evaluate` metrics."""
    for label, m in metrics.items():
        for key, value in _flatten(m):
            if isinstance(value, float) and not key.endswith("step"):
                print(f"| {label} (step {m['step']}).{key} | {value:.4g} |")


def _print_chains(images: str, chains: dict[str, dict]) -> None:
    print(f"\n| Detector, three runs chained ({images}) "
          "| markers P / R / F1 | recall, fully visible | ID accuracy all / full | cut share of fully visible "
          "| median px centre, TL, TR, BL, BR (not cut) | crosspoints visibility P / R | crosspoint px median / p95 "
          "| s/image | stages s/image: localize, recognize, vote, complete, crosspoints "
          "|\n|---|---|---|---|---|---|---|---|---|---|")
    for label, d in chains.items():
        m, ids, xp = d["markers"], d["id_accuracy"], d["crosspoints"]
        points = ", ".join(_number(d["point_error_px"]["not_partial"][k]["median"], ".2f")
                           for k in ("centre", "TL", "TR", "BL", "BR"))
        print(f"| {label} | {m['all']['precision']:.3f} / {m['all']['recall']:.3f} / {m['all']['f1']:.3f} | "
              f"{m['full']['recall']:.3f} | {_number(ids['all']['accuracy'], '.3f')} / "
              f"{_number(ids['full']['accuracy'], '.3f')} | {_number(d['partial']['full']['fraction'], '.3f')} | "
              f"{points} | {xp['visibility']['precision']:.3f} / {xp['visibility']['recall']:.3f} | "
              f"{_number(xp['error_px']['median'], '.3f')} / {_number(xp['error_px']['p95'], '.3f')} | "
              f"{d['seconds_per_image']:.3f} | {_stages(d, d['images'])} |")


def _print_extra(extra: dict) -> None:
    """The --extra-heldout tables: each network's metrics, the chain, the recognizer's top-1 by size."""
    images = f"{extra['images']} renders of --extra-heldout"
    print(f"\n| metric ({images}) | value |\n|---|---|")
    _print_metrics(extra["metrics"])
    _print_chains(images, extra["detector"])
    _print_top1(images, {"": extra["recognizer_top1"]})


def _print_top1(images: str, recognizers: dict[str, dict]) -> None:
    """Per recognizer label, its top-1 given the true points (`networks.recognizer_top1.top1`) per group,
    then per group and marker size, then whole markers by the share of their crosspoints visible (in the
    size column; records of older results have none)."""
    print(f"\n| recognizer, top-1 given the true points ({images}) | markers | size px | count | top-1 "
          "|\n|---|---|---|---|---|")
    for label, record in recognizers.items():
        for group, r in record["groups"].items():
            print(f"| {label} | {group} | all | {r['markers']} | {r['top1']:.3f} |")
        for group, bins in record["by_size"].items():
            for size, r in bins.items():
                print(f"| {label} | {group} | {size} | {r['markers']} | {r['top1']:.3f} |")
        for share, r in record.get("by_visible", {}).items():
            print(f"| {label} | all five points visible | {share} | {r['markers']} | {r['top1']:.3f} |")


def _stages(record: dict, images: float) -> str:
    stages = record.get("stage_seconds") or {}
    return ", ".join(f"{seconds / images:.3f}" for seconds in stages.values()) or "-"


def _number(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _flatten(d: dict, prefix: str = "") -> list[tuple[str, object]]:
    items = []
    for key, value in d.items():
        name = f"{prefix}{key}"
        items += _flatten(value, name + ".") if isinstance(value, dict) else [(name, value)]
    return items


if __name__ == "__main__":
    main()
