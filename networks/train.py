"""Train one of the three networks: one short loop shared by all of them.

    python -m networks.train localizer --data out/ds --out runs/loc --pretrained resnet18.pth
    python -m networks.train recognizer --data synth --garment out/ds --out runs/rec --steps 20000
    python -m networks.train crosspoints --data out/ds --synth-weight 0.5 --out runs/xp
    python -m networks.train crosspoints --data out/ds --out runs/xp --resume --time-limit 540
    python -m networks.train localizer --data out/ds --synth-weight 0.5 --shards shards/loc --out runs/loc
    python -m networks.train recognizer --data my_capture_ds --out runs/rec_ft --init runs/rec/best.pt --steps 5000
    python -m networks.train --recipe modules_reader --data out/datasets/modules_reader --out runs/reader

Data: `--data DIR [DIR ...]` are factory dataset folders (their train splits joined for training,
their val splits for validation), mixed with synthesized samples at `--synth-weight`; `--data synth` trains and validates on
the synthesizer alone.  Synthesized training samples come from the synthesizer on the fly, or from a
shard folder written before (`--shards`, `python -m networks.shards write`; validation stays on the
rendered val split, or on the fly).  The garment (`--garment`, default the dataset's template.npz)
gives the marker IDs that are synthesized and that the recognizer classifies among
(`TrainConfig.recognizer_classes`, `--recognizer-ids`: "garment", the reference's; "codebook"; or "modules",
a reader of the code modules decoded against the codebook, whose synthesized crops are of every
codebook ID unless `--garment` is given).  The run folder gets `config.json` (the run's settings, recorded
by `assets.fileio.record_stage`: a later call with other settings is refused, naming each, except
those of `RESUMABLE_CHANGES`), `log.jsonl` (one JSON line per logged step
with the loss and its parts, one per validation with the metrics of `networks.evaluate`, and one
per call at its first step, `startup`: seconds from the call's start to the training loop, then to the
first batch and the first finished step),
`last.pt` (every `checkpoint_every` steps, at the end, on Ctrl-C and at --until-step/--time-limit) and
`best.pt` (the lowest validation loss).  `--resume` continues from `last.pt` with the same model,
optimizer, learning-rate schedule, step, data order and random state; the run's saved config is the
base and flags given on the command line override it.

`--recipe NAME` trains a network of a recipe file (`networks.recipe`): the recipe's table is the
config (flags given still override it, and the run folder's `recipe.json` records the recipe, its
file's SHA-256 and what the flags changed), `--data` is the folder `factory.dataset build --recipe`
made (checked to be this recipe's data; its training parts are the data), and a recipe starting from
stored weights writes the pinned ones from the repository's history (or checks the `--init` file
given against their SHA-256, on a machine without the history).

Batches follow a fixed order (`StepOrder`): step s takes positions s*B .. (s+1)*B - 1 of a sequence of
epochs, each an order of the training set seeded by (seed, epoch), and every item is itself seeded by
(seed, epoch, index) (`networks.data`), so a resumed run sees exactly the batches the uninterrupted
run would have seen.  Mixed precision (bf16 autocast) on CUDA.

Several GPUs (or CPU processes): ``torchrun --nproc-per-node N -m networks.train ...`` trains with
DistributedDataParallel (`networks.distributed`): `batch_size` stays the global batch, each rank
takes an equal share of every step's batch, BatchNorm uses the global batch's statistics, and only
rank 0 writes the run folder, logs and shows the progress bar.  Measured on H200s, two ranks train
the crosspoint network at half the step rate of one GPU: not yet a speed-up.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import signal
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Subset
from tqdm import tqdm

from assets.fileio import record_stage
from assets.pattern import PatternSpec, generate_codebook
from networks.augment import Augment, ViewWarp
from networks.checkpoint import check_pattern, checkpoint_spec, read_checkpoint, save_checkpoint
from networks.codes import module_targets
from networks.config import RECOGNIZER_CLASSES, TASKS, TrainConfig
from networks.distributed import RankBatches, Ranks, any_rank, join, leave, mean_over_ranks, parallel, rank_device
from networks.data import (JoinedDataset, MixedDataset, RenderedDataset, ShardDataset, SynthDataset, dataset_spec,
                           garment_marker_ids, shard_geometry_problem)
from networks.evaluate import evaluate_model, resolve_device
from networks.flags import CROP_JITTER, SEED, WHOLE_MARKERS_ONLY, ConfigFlag, add_config_flags, config_overrides
from networks.recipe import check_data_folder, load_recipe, stored_init
from networks.synth import SynthConfig
from networks.tasks import autocast, build_model, forward
from networks.workers import one_thread, worker_context

log = logging.getLogger(__name__)

#: config fields a resumed run may change (they do not alter what the network learns from); any other
#: difference from the run folder's record (`RUN_RECORD`) is refused by name
RESUMABLE_CHANGES = ("steps", "num_workers", "log_every", "val_every", "val_samples", "checkpoint_every")
#: the run folder's record of its config (`assets.fileio.record_stage`), beside its checkpoints
RUN_RECORD = "config.json"
#: the TrainConfig fields the CLI sets, as flags made from the fields (`networks.flags`); the others
#: (TRAIN_CONFIG_ONLY; the task is the positional argument) come from --config, a recipe or the defaults
TRAIN_FLAGS = (
    ConfigFlag("steps", "optimizer steps in total"),
    ConfigFlag("batch_size", "samples per step (crops for the crop networks), over all ranks"),
    ConfigFlag("lr", "peak learning rate (Adam, cosine decay)"),
    ConfigFlag("pretrained", "torchvision ImageNet ResNet state-dict file for the backbone", metavar="PTH"),
    ConfigFlag("init", "a checkpoint of this task to start a new run from (its weights; new optimizer and "
               "schedule): fine-tuning, or training continued elsewhere", metavar="PT"),
    ConfigFlag("synth_weight", "share of synthesized samples mixed into a dataset (0-1)"),
    ConfigFlag("recognizer_classes", "recognizer: 'garment' classifies the garment's marker IDs (the reference; "
               "default), 'codebook' every codebook ID, 'modules' reads the marker's code modules and decodes them "
               "against the codebook, so garments never trained on are recognised",
               flag="--recognizer-ids", aliases=("--recognizer-classes",), choices=RECOGNIZER_CLASSES),
    CROP_JITTER,
    SEED,
    ConfigFlag("num_workers", "data loading processes (per rank)", flag="--workers", metavar="N"),
    ConfigFlag("image_size", "side of the localizer's training images, pixels", metavar="PX"),
    ConfigFlag("augment", "train without augmentation (photometric, and the localizer's view warp)",
               flag="--no-augment", sets=False),
    ConfigFlag("view_warp", "localizer: no random zoom, rotation and compression of rendered images (ViewWarp)",
               flag="--no-view-warp", sets=False),
    WHOLE_MARKERS_ONLY,
    ConfigFlag("mixed_precision", "float32 on CUDA too", flag="--no-mixed-precision", sets=False),
)
TRAIN_CONFIG_ONLY = ("weight_decay", "warmup_steps", "min_lr_ratio", "log_every", "val_every", "val_samples",
                     "checkpoint_every")
#: the logit of the codebook IDs outside a recognizer's classes: never the arg max, nothing of the softmax
MASKED_LOGIT = -1e4
#: the validation synthesizer's seed is the training seed plus this, so the two never share samples
VAL_SEED_OFFSET = 1_000_003
#: fit_to_time_limit: the step rate is measured from this many steps after the start (data workers and
#: cuDNN's algorithm search are behind by then) over this share of the time limit, and the schedule
#: is planned to end at this share of the time left (validations and checkpoints vary the pace)
FIT_SKIP_STEPS, FIT_PROBE_SHARE, FIT_MARGIN = 10, 0.05, 0.93
#: ... and fitted once more, at the rate measured over this share of the time limit after the first
#: fit: a first probe inside a slow start (caches filling, other runs starting) once planned a
#: localizer at a third of its steady rate, and its GPU idled for the last 10 minutes
FIT_REFIT_SHARE = 0.2


class StepOrder(Dataset):
    """The training sequence of a run: item p (p = step * batch_size + k) is an item of `dataset`.

    Position p lies in epoch e = p // n (n = len(dataset)); the dataset is told the epoch
    (`set_epoch`: new augmentations, new synthetic samples) and, when `shuffle`, item p is the
    (p mod n)-th of epoch e's order, drawn from a generator seeded by (seed, e): runs of `chunk`
    consecutive items in random order, shuffled within windows of `window` runs.  Consecutive items
    of a crop dataset are crops of one image, so a batch reads few images (`RenderedDataset` caches
    them per worker) and is still drawn from all over the dataset.  Without `shuffle` (synthetic data,
    i.i.d. already) item p is item p mod n."""

    def __init__(self, dataset: Dataset, length: int, seed: int, shuffle: bool, chunk: int = 1, window: int = 32):
        if len(dataset) < 1:
            raise ValueError("StepOrder: the training set is empty")
        self.dataset, self.length, self.seed, self.shuffle = dataset, length, seed, shuffle
        self.chunk, self.window = chunk, window
        self._orders: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return self.length

    def order(self, epoch: int) -> np.ndarray:
        """(n,) the dataset's item indices in epoch `epoch`'s order."""
        n = len(self.dataset)
        if not self.shuffle:
            return np.arange(n)
        if epoch not in self._orders:
            rng = np.random.default_rng([self.seed, epoch])
            index = np.arange(n)
            chunk_rank = rng.permutation(-(-n // self.chunk))
            by_chunk = np.argsort(chunk_rank[index // self.chunk], kind="stable")
            window = np.arange(n) // (self.chunk * self.window)
            self._orders = {epoch: by_chunk[np.lexsort((rng.random(n), window))]}  # keep one epoch
        return self._orders[epoch]

    def __getitem__(self, position: int) -> dict:
        epoch, offset = divmod(int(position), len(self.dataset))
        if hasattr(self.dataset, "set_epoch"):
            self.dataset.set_epoch(epoch)
        # unshuffled: the offset itself (`order` would build an arange of a mixed set's whole length,
        # steps x batch items, for every item: 50 ms each at 200,000 steps of 256)
        return self.dataset[int(self.order(epoch)[offset]) if self.shuffle else offset]


#: crops a crop task takes of each synthesized sample (a centred 256 x 256 sample shows about 90
#: markers, and rendering it is most of an item's cost): synthesized recognizer items, augmented, on
#: one core: 278 items/s at 48, 133 at 16 (rendered crops: 365)
SYNTH_CROPS_PER_SAMPLE = 48


def data_loader(dataset: Dataset, num_workers: int, **kwargs: object) -> DataLoader:
    """A DataLoader whose `num_workers` workers come from a fork server (`networks.workers.worker_context`,
    which says why), each with one BLAS, OpenMP and OpenCV thread."""
    if num_workers == 0:
        return DataLoader(dataset, **kwargs)
    return DataLoader(dataset, num_workers=num_workers, multiprocessing_context=worker_context("networks.train"),
                      worker_init_fn=one_thread, persistent_workers=True, **kwargs)


def init_weights(model: torch.nn.Module, config: TrainConfig, spec: PatternSpec, class_ids: np.ndarray | None
                 ) -> None:
    """Load the weights of the checkpoint `config.init` (same task and pattern; any dtype) into the
    new run's `model`.  A recognizer's classes that the checkpoint had masked off (it was trained on
    another garment's IDs) start from zero weights and bias, not from the masked logit.  A module
    reader started from an ID classifier (or the other way) takes its backbone and starts its output
    layer (``backbone.fc``, IDs or modules) afresh."""
    path = Path(config.init)
    data = read_checkpoint(path)
    if data["task"] != config.task:
        raise ValueError(f"{path}: a {data['task']} checkpoint, cannot start a {config.task} run from it")
    check_pattern(data, spec, source=str(path))
    state = data["model"]
    reads_modules = (config.task == "recognizer") and (config.recognizer_classes == "modules")
    if reads_modules != (data["config"].get("recognizer_classes") == "modules"):
        state = {k: v for k, v in state.items() if not k.startswith("backbone.fc.")}
        log.info("%s: its backbone only (the output layer reads %s)", path, "modules" if reads_modules else "IDs")
    try:
        missing, unexpected = model.load_state_dict(state, strict=False)
    except RuntimeError as exc:
        raise ValueError(f"{path}: its weights do not fit this {config.task} network: {str(exc).splitlines()[0]}") from exc
    if unexpected or any(not k.startswith("backbone.fc.") or len(state) == len(data["model"]) for k in missing):
        raise ValueError(f"{path}: its weights do not fit this {config.task} network (missing {missing[:3]}, "
                         f"unexpected {unexpected[:3]})")
    trained = data.get("recognizer_ids")
    if class_ids is not None and trained is not None:
        fresh = np.setdiff1d(class_ids, np.asarray(trained, dtype=np.int64))
        if len(fresh):
            with torch.no_grad():
                index = torch.as_tensor(fresh, device=model.backbone.fc.weight.device)
                model.backbone.fc.weight[index] = 0.0
                model.backbone.fc.bias[index] = 0.0
    log.info("%s run starts from the weights of %s (its step %d)", config.task, path, int(data["step"]))


def restrict_classes(model: torch.nn.Module, marker_ids: np.ndarray) -> None:
    """Make a `MarkerRecognizer` (one output per codebook ID) a classifier over `marker_ids` only.

    The other IDs' rows of ``backbone.fc`` become zero with bias `MASKED_LOGIT` and get no gradient
    (hooks), so their logits stay far below every class's: softmax and cross-entropy are those of an
    N-way classifier (N = len(marker_ids)), while output k stays marker ID k for checkpoints, the
    evaluation and the Detector.  Call before loading a state dict of a restricted run (the hooks are
    not part of it)."""
    fc = model.backbone.fc
    ids = np.asarray(marker_ids, dtype=np.int64)
    if ids.ndim != 1 or len(ids) < 2 or ids.min() < 0 or ids.max() >= fc.out_features:
        raise ValueError(f"restrict_classes: need >= 2 marker IDs in 0..{fc.out_features - 1}, got {len(ids)} "
                         f"IDs in {ids.min(initial=0)}..{ids.max(initial=0)}")
    keep = torch.zeros(fc.out_features, dtype=torch.bool, device=fc.weight.device)
    keep[torch.as_tensor(ids, device=fc.weight.device)] = True
    with torch.no_grad():
        fc.weight[~keep] = 0.0
        fc.bias[~keep] = MASKED_LOGIT
    mask = keep.to(fc.weight.dtype)
    fc.weight.register_hook(lambda grad: grad * mask[:, None])
    fc.bias.register_hook(lambda grad: grad * mask)


def lr_factor(step: int, config: TrainConfig) -> float:
    """Learning-rate multiplier at `step`: linear warm-up, then cosine decay to `min_lr_ratio`."""
    if step < config.warmup_steps:
        return (step + 1) / config.warmup_steps
    span = max(1, config.steps - config.warmup_steps)
    progress = min(1.0, (step - config.warmup_steps) / span)
    return config.min_lr_ratio + (1 - config.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * progress))


#: what `data` is throughout: "synth", one factory dataset folder, or several (a recipe's parts)
Data = str | Path | list[Path] | tuple[Path, ...]


def data_folders(data: Data) -> list[Path]:
    """The factory dataset folders of `data` ([] for "synth"); each must exist."""
    if isinstance(data, (list, tuple)):
        folders = [Path(d) for d in data]
        if not folders:
            raise ValueError("no dataset folders given")
    elif str(data) == "synth":
        return []
    else:
        folders = [Path(data)]
    for root in folders:
        _dataset_root(root)
    return folders


def _describe(data: Data) -> str:
    folders = data_folders(data)
    return "synth" if not folders else ", ".join(str(f) for f in folders)


def training_spec(data: Data, pattern: str | Path | None = None) -> PatternSpec:
    """The pattern to train on: the `pattern` JSON file, else the datasets' own (`template.npz`; several
    folders must share it), else the default `PatternSpec()` (synthetic data)."""
    if pattern is not None:
        return PatternSpec.load(pattern)
    specs = [(root, dataset_spec(root)) for root in data_folders(data) if (root / "template.npz").is_file()]
    for root, spec in specs[1:]:
        if spec.to_dict() != specs[0][1].to_dict():
            raise ValueError(f"{root}: printed with another pattern than {specs[0][0]} (template.npz layout_json.spec); "
                             "train on folders of one pattern, or give --pattern")
    if specs:
        return specs[0][1]
    log.info("no pattern given and none in %s: training on the default PatternSpec()", _describe(data))
    return PatternSpec()


def make_datasets(config: TrainConfig, data: Data, spec: PatternSpec, shards: str | Path | None = None,
                  marker_ids: np.ndarray | None = None) -> tuple[Dataset, Dataset]:
    """(training set, validation set) of `config.task` from factory dataset folders (their train and
    val splits joined) and/or the synthesizer (`data` == "synth"); synthesized training samples from the shard folder `shards` when
    given; marker_ids: the IDs to synthesize (default all); see the module docstring."""
    task = config.task
    augment = Augment() if config.augment else None
    length = config.steps * config.batch_size
    size = (config.image_size, config.image_size) if task == "localizer" else None  # crops: the synthesizer's own

    geometry = config.crop_geometry()
    jitter = geometry.jitter_px
    partial = config.recognizer_partial and task == "recognizer"

    def synth(count: int, seed: int, with_augment: Augment | None, image_size: tuple[int, int] | None,
              stored: bool = True, crop_jitter_px: float = 0.0) -> Dataset:
        if shards is None or not stored:
            synth_config = None if task == "localizer" else SynthConfig(image_size=(256, 256), centred=True,
                                                                         crop_jitter_px=crop_jitter_px,
                                                                         recognizer_partial=partial)
            return SynthDataset(task, spec, length=count, seed=seed, config=synth_config, image_size=image_size,
                                augment=with_augment, marker_ids=marker_ids, crops_per_sample=SYNTH_CROPS_PER_SAMPLE)
        dataset = ShardDataset(shards, task, with_augment, spec, seed)
        if problem := shard_geometry_problem(shards, dataset.meta, geometry):
            raise ValueError(problem)
        written_partial = bool(dataset.meta["synth"].get("recognizer_partial", False))
        if task == "recognizer" and written_partial != partial:
            raise ValueError(f"{shards}: recognizer crops of {'whole and partial' if written_partial else 'whole'} "
                             f"markers, but this run's recognizer_partial is {partial}; write shards "
                             f"{'without' if partial else 'with'} --whole-markers-only")
        if marker_ids is not None and not np.isin(dataset.marker_ids if dataset.marker_ids is not None
                                                  else np.arange(spec.num_ids), marker_ids).all():
            raise ValueError(f"{shards}: the shards hold marker IDs outside the {len(marker_ids)} of this run; "
                             "write them with its garment (--garment)")
        if image_size is not None and tuple(dataset.meta["synth"]["image_size"]) != tuple(image_size):
            raise ValueError(f"{shards}: shards of {dataset.meta['synth']['image_size']} images, but this run "
                             f"trains on {list(image_size)} (image_size)")
        return dataset

    folders = data_folders(data)
    if not folders:
        return (synth(length, config.seed, augment, size, crop_jitter_px=jitter),
                synth(config.val_samples, config.seed + VAL_SEED_OFFSET, None, size, stored=False))
    view_warp = ViewWarp() if task == "localizer" and config.augment and config.view_warp else None
    parts = {"train": [], "val": []}
    for k, root in enumerate(folders):  # each folder its own seed: their items k do not share draws
        parts["train"].append(RenderedDataset(root, "train", task, augment=augment, spec=spec, seed=config.seed + k,
                                              crop_px=config.image_size if task == "localizer" else None,
                                              crop_jitter_px=jitter, view_warp=view_warp, partial_markers=partial,
                                              decode_ahead=True))
        parts["val"].append(RenderedDataset(root, "val", task, spec=spec, seed=config.seed))
        for split in parts:
            if len(parts[split][-1]) == 0:
                raise ValueError(f"{root}: the {split} split has no {task} samples")
    rendered, val = (parts[s][0] if len(folders) == 1 else JoinedDataset(parts[s]) for s in ("train", "val"))
    if task == "localizer":  # synthesized images take the size of the rendered crops, so batches can mix them
        height, width = rendered[0]["image"].shape[1:]
        size = (width, height)
    if config.synth_weight >= 1.0:
        return synth(length, config.seed, augment, size, crop_jitter_px=jitter), val
    if config.synth_weight > 0.0:
        mixed = MixedDataset([rendered, synth(length, config.seed, augment, size, crop_jitter_px=jitter)],
                             [1.0 - config.synth_weight, config.synth_weight], length=length, seed=config.seed)
        return mixed, val
    return rendered, val


def _dataset_root(data: Data) -> Path:
    root = Path(data)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such dataset folder (give a factory dataset folder or 'synth')")
    return root


def run_marker_ids(config: TrainConfig, data: Data, garment: str | Path | None) -> tuple[np.ndarray | None,
                                                                                  np.ndarray | None]:
    """(the garment's marker IDs or None, the recognizer's class IDs or None for the whole codebook).
    The garment is `garment` (a dataset folder or template.npz), else the datasets' garments (the
    union of their template.npz IDs); a module reader ("modules") learns from every codebook ID unless
    `garment` is given."""
    reads_modules = config.task == "recognizer" and config.recognizer_classes == "modules"
    if garment is not None:
        ids = garment_marker_ids(garment)
    elif not reads_modules:
        garments = [root for root in data_folders(data) if (root / "template.npz").is_file()]
        ids = np.unique(np.concatenate([garment_marker_ids(root) for root in garments])) if garments else None
    else:
        ids = None
    if config.task != "recognizer" or config.recognizer_classes != "garment":
        return ids, None
    if ids is None:
        raise ValueError(f"recognizer_classes 'garment' needs the garment whose marker IDs are the classes: "
                         f"{_describe(data)} has no template.npz; pass --garment (a factory dataset folder or its "
                         "template.npz) or --recognizer-ids codebook or modules")
    return ids, ids


def _append_log(path: Path, record: dict) -> None:
    with path.open("a") as f:
        f.write(json.dumps(record) + "\n")


def record_run(out: Path, config: TrainConfig, write: bool = True) -> None:
    """Check `config` against the run folder's record of its config (`RUN_RECORD`, written by the
    calls before) and, with `write`, record it: a call with another config is refused, naming each
    setting that differs, except the `RESUMABLE_CHANGES`, which the record takes."""
    try:
        record_stage(out / RUN_RECORD, config.to_dict(), changeable=RESUMABLE_CHANGES, write=write)
    except ValueError as exc:
        raise ValueError(f"{exc} (a resumed run may change only {', '.join(RESUMABLE_CHANGES)})") from None


def train(config: TrainConfig, data: Data, out: str | Path, device: str | torch.device | None = None,
          resume: bool = False, spec: PatternSpec | None = None, until_step: int | None = None,
          time_limit_s: float | None = None, progress: bool = True, shards: str | Path | None = None,
          garment: str | Path | None = None, ranks: Ranks | None = None, fit_to_time_limit: bool = False) -> dict:
    """Train `config.task` on `data` (factory dataset folders, one or a list, or "synth") into the run
    folder `out`.

    shards: a shard folder of `config.task` (`networks.shards`) to draw the synthesized training
    samples from.  garment: a factory dataset folder or template.npz whose marker IDs are
    synthesized and, for the recognizer, are its classes (default: `data`'s template.npz).
    spec: the pattern (default `training_spec(data)`).  resume: continue from `out/last.pt` (a fresh
    run refuses a folder that already holds one); either way a folder whose record (`RUN_RECORD`,
    `record_run`) names another config is refused before any work.  until_step / time_limit_s: stop early at that step
    or after that many seconds, writing `last.pt` (resume later).  Ctrl-C writes `last.pt` and
    re-raises.  fit_to_time_limit: shorten the schedule (`config.steps`, so the cosine decay) to end
    within time_limit_s at the step rate measured early in this call (`FIT_SKIP_STEPS`,
    `FIT_PROBE_SHARE`, `FIT_MARGIN`) and again at the steady rate (`FIT_REFIT_SHARE`), never beyond
    config.steps; the fitted steps are saved with the run's
    config, so a resumed run keeps them.  Returns {"step", "finished", "best_val_loss", "last", "best",
    "val", "steps"} (the last validation metrics, or None; the planned steps).  With
    config.num_workers > 0 the data-loading workers come from a fork server (`data_loader`): a
    script that calls `train` needs the usual
    ``if __name__ == "__main__":`` guard.

    ranks: this process's place among several training processes (default: from torchrun's
    environment, `networks.distributed.Ranks.from_environment`; one process without it): the
    process group is joined here and left at the end, rank r trains on its share of every global
    batch (on cuda:LOCAL_RANK with CUDA), and only rank 0 writes the run folder and shows progress."""
    ranks = Ranks.from_environment() if ranks is None else ranks
    device = rank_device(ranks, resolve_device(device))
    ranks.share(config.batch_size)  # a batch the ranks cannot share equally is refused before any work
    if fit_to_time_limit and time_limit_s is None:
        raise ValueError("fit_to_time_limit needs a time limit (--time-limit)")
    joined = join(ranks, device)
    try:
        return _train(config, data, Path(out), device, resume, spec, until_step, time_limit_s,
                      progress and ranks.main, shards, garment, ranks, fit_to_time_limit)
    finally:
        if joined:
            leave()


def _train(config: TrainConfig, data: Data, out: Path, device: torch.device, resume: bool,
           spec: PatternSpec | None, until_step: int | None, time_limit_s: float | None, progress: bool,
           shards: str | Path | None, garment: str | Path | None, ranks: Ranks, fit_to_time_limit: bool) -> dict:
    entered = time.monotonic()
    last_path, best_path, log_path = out / "last.pt", out / "best.pt", out / "log.jsonl"
    saved = None
    if last_path.exists():
        if not resume:
            raise ValueError(f"{out}: already holds a training run (last.pt); pass --resume or use another --out")
        saved = read_checkpoint(last_path, device)
        if saved.get("optimizer") is None:
            raise ValueError(f"{last_path}: holds no optimizer state (a slim checkpoint?), so the run cannot "
                             "resume from it; start a new run from its weights with --init")
        if saved["task"] != config.task:
            raise ValueError(f"{last_path}: a {saved['task']} run, cannot resume it as {config.task}")
        saved_spec = checkpoint_spec(saved)
        if spec is not None:
            check_pattern(saved, spec, source=str(last_path))
        spec = saved_spec
    elif resume:
        log.info("%s: no last.pt yet, starting a new run", out)
    record_run(out, config, write=False)  # before any work; rank 0 writes the record once the folder is made
    if spec is None:
        spec = training_spec(data)
    if saved is not None and saved.get("recognizer_ids") is not None:  # the classes are the run's, once chosen
        garment_ids = class_ids = np.asarray(saved["recognizer_ids"], dtype=np.int64)
    else:
        garment_ids, class_ids = run_marker_ids(config, data, garment)

    train_set, val_set = make_datasets(config, data, spec, shards, garment_ids)
    torch.manual_seed(config.seed)
    model = build_model(config.task, spec.num_ids, spec.crosspoints_per_side,
                        pretrained=None if saved is not None else config.pretrained,
                        recognizer_classes=config.recognizer_classes,
                        modules_per_side=spec.modules_per_side, crops=config.crop_geometry()).to(device)
    if device.type == "cuda":  # NHWC convolutions: faster on tensor cores
        model = model.to(memory_format=torch.channels_last)
    if saved is None and config.init is not None:
        init_weights(model, config, spec, class_ids)
    if class_ids is not None:
        restrict_classes(model, class_ids)
    # a module reader's targets: the module grids of the batch's IDs, rows of this (num_ids, n * n) table
    codes = module_targets(generate_codebook(spec)).to(device) \
        if config.task == "recognizer" and config.recognizer_classes == "modules" else None
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)

    def schedule(step: int) -> float:  # reads `config` when called: a fitted schedule takes effect at once
        return lr_factor(step, config)

    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, schedule)
    step, best_val = 0, math.inf
    if saved is not None:
        model.load_state_dict(saved["model"])
        optimizer.load_state_dict(saved["optimizer"])
        scheduler.load_state_dict(saved["scheduler"])
        step, best_val = int(saved["step"]), float(saved.get("best_val_loss", math.inf))
        torch.set_rng_state(saved["rng"]["torch"].cpu())
        if device.type == "cuda" and saved["rng"]["cuda"]:
            torch.cuda.set_rng_state_all([s.cpu() for s in saved["rng"]["cuda"]])
        log.info("resuming %s at step %d of %d", last_path, step, config.steps)
    if ranks.main:
        out.mkdir(parents=True, exist_ok=True)
        record_run(out, config)
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = True

    stop = min(config.steps, until_step) if until_step is not None else config.steps
    sequence = StepOrder(train_set, config.steps * config.batch_size, config.seed,
                         shuffle=isinstance(train_set, (RenderedDataset, ShardDataset, JoinedDataset)),
                         chunk=32 if isinstance(train_set, (RenderedDataset, JoinedDataset))
                         and config.task != "localizer" else 1)
    batches = RankBatches(step, stop, config.batch_size, ranks)
    # own generators: creating a loader draws a seed, which must not disturb the global random state
    loader = data_loader(sequence, config.num_workers, batch_sampler=batches, pin_memory=device.type == "cuda",
                         generator=torch.Generator().manual_seed(config.seed + step))
    spread = np.unique(np.linspace(0, len(val_set) - 1, min(len(val_set), config.val_samples)).astype(int))
    val_items = Subset(val_set, spread.tolist())  # evenly over the split: crops of many images
    val_loader = data_loader(val_items, config.num_workers, batch_size=config.batch_size,
                             generator=torch.Generator().manual_seed(config.seed))
    val_metrics = None

    trained = parallel(model, ranks, device)  # `model` itself for one process

    def checkpoint(path: Path, with_optimizer: bool = True) -> None:
        if not ranks.main:
            return
        save_checkpoint(path, config.task, model, config, spec, optimizer if with_optimizer else None,
                        scheduler if with_optimizer else None, step, val_metrics or {},
                        extra={"best_val_loss": best_val, "data": _describe(data),
                               "shards": None if shards is None else str(shards),
                               "recognizer_ids": None if class_ids is None else class_ids.tolist()})

    def validate() -> None:  # rank 0 alone; the others wait for it at the next step's all-reduce
        nonlocal val_metrics, best_val
        if not ranks.main:
            return
        val_metrics = evaluate_model(config.task, model, val_loader, device, spec, config.mixed_precision)
        _append_log(log_path, {"step": step, "val": val_metrics})
        if val_metrics["loss"]["total"] < best_val:
            best_val = val_metrics["loss"]["total"]
            checkpoint(best_path, with_optimizer=False)

    # under DDP the MSEs divide by the global batch's target count, so the ranks' averaged gradients
    # are the single-process ones even when the ranks' counts differ
    count_mean = (lambda count: mean_over_ranks(count, ranks)) if ranks.distributed else None
    started = time.monotonic()
    # fit_to_time_limit: (first step timed, its clock, the share of the time limit it is timed over)
    probe = (step + FIT_SKIP_STEPS, None, FIT_PROBE_SHARE) if fit_to_time_limit else None
    longest = config.steps  # a fit never plans beyond the configured schedule
    fits = 0

    def fit_schedule() -> None:
        """Plan `config.steps` to end within the time limit at the rate measured since the probe began
        (the same number on every rank: their plans are averaged); after the first fit, time the
        steps again (`FIT_REFIT_SHARE`) and fit once more."""
        nonlocal config, stop, probe, fits
        first, clock, _ = probe
        now = time.monotonic()
        rate = (step - first) / max(now - clock, 1e-9)
        planned = step + rate * (time_limit_s - (now - started)) * FIT_MARGIN
        planned = int(mean_over_ranks(torch.tensor([planned], dtype=torch.float64, device=device), ranks).item())
        planned = max(step + 1, min(longest, planned))
        log.info("%s: %.2f steps/s; the schedule is fitted to the time limit: %d steps (was %d)",
                 config.task, rate, planned, config.steps)
        config = config.replace(steps=planned)
        stop = planned if until_step is None else min(until_step, planned)
        bar.total = planned
        fits += 1
        probe = (step, now, FIT_REFIT_SHARE) if fits == 1 else None
        if ranks.main:
            record_run(out, config)  # steps may change

    model.train()
    bar = tqdm(total=config.steps, initial=step, desc=f"train {config.task}", unit="step", disable=not progress)
    running = None
    startup = {"setup_s": started - entered}  # where a call's first seconds go: logged once, at its first step
    try:
        for batch in loader:
            if "first_batch_s" not in startup:
                startup["first_batch_s"] = time.monotonic() - started
            with autocast(device, config.mixed_precision):
                _, loss, parts = forward(config.task, trained, batch, device, count_mean, codes)
            # the global batch's loss and parts (the mean of the ranks'), so that all ranks stop together
            reported = mean_over_ranks(torch.stack([loss.detach().float(), *(v.float() for v in parts.values())]),
                                       ranks).tolist()
            value = reported[0]
            if not math.isfinite(value):
                raise RuntimeError(f"{config.task} loss is {value} at step {step}; lower --lr")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            scheduler.step()
            step += 1
            running = value if running is None else 0.98 * running + 0.02 * value
            if "first_step_s" not in startup:
                startup["first_step_s"] = time.monotonic() - started
                if ranks.main:
                    _append_log(log_path, {"step": step, "startup": startup})
            bar.update(1)
            bar.set_postfix(loss=f"{running:.4g}")
            if ranks.main and (step % config.log_every == 0 or step == stop):
                _append_log(log_path, {"step": step, "loss": value, **dict(zip(parts, reported[1:])),
                                       "lr": scheduler.get_last_lr()[0], "elapsed_s": time.monotonic() - started})
            if step % config.val_every == 0 or step == config.steps:
                validate()
            if step % config.checkpoint_every == 0:
                checkpoint(last_path)
            if time_limit_s is not None and any_rank(ranks.main and time.monotonic() - started > time_limit_s,
                                                    ranks, device):
                log.info("time limit of %.0f s reached at step %d", time_limit_s, step)
                break
            if probe is not None:  # fit_to_time_limit: time the steps from probe[0], then fit
                if probe[1] is None:
                    probe = (step, time.monotonic(), probe[2]) if step >= probe[0] else probe
                elif any_rank(ranks.main and time.monotonic() - probe[1] >= probe[2] * time_limit_s,
                              ranks, device):
                    fit_schedule()
            if step >= stop:
                break
    except KeyboardInterrupt:
        checkpoint(last_path)
        if ranks.main:
            log.warning("interrupted at step %d: %s written; continue with --resume", step, last_path)
        raise
    finally:
        bar.close()
    checkpoint(last_path)
    return {"step": step, "finished": step >= config.steps, "best_val_loss": best_val if best_val < math.inf else None,
            "last": str(last_path), "best": str(best_path) if best_path.exists() else None, "val": val_metrics,
            "steps": config.steps}


def _config_from_args(args: argparse.Namespace, recipe_config: TrainConfig | None = None) -> TrainConfig:
    """Saved run config (--resume), else --config or the recipe's, else the task's defaults; then the
    flags given."""
    last = args.out / "last.pt"
    if args.resume and last.exists():
        saved = read_checkpoint(last)
        base = TrainConfig.from_dict(saved["config"], source=f"{last}:config")
    elif args.config is not None:
        base = TrainConfig.load(args.config)
    elif recipe_config is not None:
        base = recipe_config
    else:
        base = TrainConfig(task=args.task)
    if base.task != args.task:
        raise ValueError(f"{args.config or last}: a {base.task} config, but the task given is {args.task}")
    overrides = config_overrides(args, TRAIN_FLAGS)
    for name in ("pretrained", "init"):  # the run's config names the files wherever it is resumed from
        if overrides.get(name) is not None:
            overrides[name] = str(Path(overrides[name]).resolve())
    return base.replace(**overrides)


def _recipe_run(args: argparse.Namespace) -> tuple[TrainConfig, Data, dict]:
    """--recipe: (the run's config, its data, the record saved as the run folder's recipe.json).  The
    recipe's network is the base config; flags given still override it, and the record lists what
    they changed."""
    recipe = load_recipe(args.recipe)
    args.task, network = recipe.network(args.task)
    if args.config is not None:
        raise ValueError("--recipe and --config both give the config; use one")
    if network.data == "synth":
        if args.data not in (None, ["synth"]):
            raise ValueError(f"{recipe.path}: its {args.task} trains on the synthesizer alone; leave out --data")
        data: Data = "synth"
    else:
        if args.data is None or len(args.data) != 1:
            raise ValueError(f"{recipe.path}: its {args.task} trains on the recipe's renders; give --data, the "
                             f"folder `python -m factory.dataset build --recipe {recipe.name}` made")
        data = check_data_folder(recipe, args.data[0])
    init = None if args.resume and (args.out / "last.pt").exists() else \
        stored_init(network, args.task, args.init, args.out / "init")
    args.init = None
    config = _config_from_args(args, network.config.replace(init=None if init is None else str(init.resolve())))
    record = recipe.record(args.task)
    mine = network.config.to_dict()
    record["changed"] = {k: v for k, v in config.to_dict().items() if k != "init" and v != mine[k]}
    return config, data, record


def _save_recipe_record(out: Path, record: dict) -> None:
    """Record the recipe in `out`/recipe.json (`assets.fileio.record_stage`): a run folder of another
    recipe, or of another version of its file, is refused by name; what the flags changed may differ."""
    record_stage(out / "recipe.json", record, changeable=("changed",))


def main(argv: list[str] | None = None) -> int:
    from assets.cli import add_device, add_out, add_progress, progress, run_cli

    parser = argparse.ArgumentParser(prog="python -m networks.train", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task", choices=TASKS, nargs="?", help="the network to train (with --recipe: default its only one)")
    parser.add_argument("--recipe", help="train a recipe's network (networks/recipes/NAME.toml, or a .toml file): "
                        "its config is the base, its data the folder factory.dataset build --recipe made")
    parser.add_argument("--data", nargs="+", metavar="DIR", help="factory dataset folders (their train and val "
                        "splits joined), or 'synth' for synthesized data only; with --recipe: its built data folder")
    add_out(parser, "run folder: config.json (the run's settings), log.jsonl, last.pt, best.pt")
    parser.add_argument("--config", type=Path, help="a TrainConfig JSON file (flags below override it; the fields "
                        f"without a flag: {', '.join(TRAIN_CONFIG_ONLY)})")
    parser.add_argument("--shards", type=Path, help="a shard folder of pre-synthesized samples of the task "
                        "(python -m networks.shards write) to draw the synthesized training samples from")
    parser.add_argument("--garment", type=Path, help="a factory dataset folder or template.npz: the marker IDs to "
                        "synthesize and to recognize (default: the dataset's template.npz)")
    parser.add_argument("--pattern", type=Path, help="PatternSpec JSON (default: the dataset's, or the default spec)")
    add_config_flags(parser, TrainConfig, TRAIN_FLAGS)
    add_device(parser)
    parser.add_argument("--resume", action="store_true", help="continue the run in --out from last.pt")
    parser.add_argument("--until-step", type=int, help="stop at this step (writes last.pt; resume later)")
    parser.add_argument("--time-limit", type=float, help="stop after this many seconds (writes last.pt)")
    parser.add_argument("--fit-time-limit", action="store_true", help="shorten --steps so that the learning-rate "
                        "schedule ends within --time-limit, at the step rate measured early in the run and again at "
                        "its steady rate")
    add_progress(parser)
    args = parser.parse_args(argv)
    args.out = Path(args.out)

    def action() -> None:
        ranks = Ranks.from_environment()
        if not ranks.main:  # rank 0 speaks for all
            logging.getLogger().setLevel(logging.WARNING)
        if args.recipe is not None:
            config, data, record = _recipe_run(args)
            if ranks.main:
                _save_recipe_record(args.out, record)
        else:
            if args.task is None or args.data is None:
                parser.error("give the task and --data, or --recipe")
            config = _config_from_args(args)
            data = args.data[0] if len(args.data) == 1 else [Path(d) for d in args.data]
        spec = PatternSpec.load(args.pattern) if args.pattern is not None else None
        result = train(config, data, args.out, args.device, args.resume, spec, args.until_step,
                       args.time_limit, progress=progress(args), shards=args.shards, garment=args.garment,
                       ranks=ranks, fit_to_time_limit=args.fit_time_limit)
        if not ranks.main:
            return
        state = "finished" if result["finished"] else "stopped (continue with --resume)"
        best = result["best_val_loss"]
        print(f"{config.task}: {state} at step {result['step']} of {result['steps']}; "
              f"best validation loss {'-' if best is None else f'{best:.4g}'}; {result['last']}")

    try:
        return run_cli(action, failures=(RuntimeError,))
    except KeyboardInterrupt:
        print(f"interrupted: {args.out / 'last.pt'} written; continue with --resume", file=sys.stderr)
        return 130


if __name__ == "__main__":
    # Ctrl-C (SIGINT) writes last.pt and stops, also where the trainer started with SIGINT ignored: a
    # shell starts `cmd &` so (and `nohup`'d benchmarks pass it on), and benchmarks/train_networks.py stops a
    # run past its budget with SIGINT; an ignored one left such a run training and the caller waiting.
    # Here only: a program calling main() keeps its own handler.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.exit(main())

