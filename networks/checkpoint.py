"""Checkpoints: one network's weights with everything needed to rebuild and trust it.

A checkpoint is a plain dict of Python types and tensors, written atomically with `torch.save` and
read with ``torch.load(path, weights_only=True)`` (no code runs on load)::

    {"format": "clothcapture-networks", "version": 1, "task": "localizer" | "recognizer" | "crosspoints",
     "config": TrainConfig.to_dict(), "pattern": {"spec": PatternSpec.to_dict(), "codebook_hash": sha256},
     "crop_geometry": CropGeometry.to_dict(),
     "num_ids": int, "crosspoints_per_side": int, "model": state dict, "optimizer": state dict | None,
     "scheduler": state dict | None, "step": int, "metrics": dict, "rng": {"torch", "cuda"}, ...extra}

The crop geometry (`assets.pattern.CropGeometry`: both crops and the training crops' jitter) is how
the network's crops were cut; the rebuilt network carries it (`crops`) and the Detector cuts its crops
so.  A checkpoint written before the record gets the one its config trained with
(`TrainConfig.crop_geometry`).

A recognizer's network follows its config's `recognizer_classes`: one output per codebook ID, or one
per code module of the pattern's marker ("modules", `networks.models.MarkerModuleReader`).

A compact checkpoint (`slim_checkpoint(..., dtype=torch.int8)`) also holds "int8_scales": {key: (out,)
float32}, one scale per output channel of each weight stored as int8 (all but `FLOAT_WEIGHTS`' of its
task, which stay float32); `read_checkpoint` returns its weights dequantized to float32, so everything
else reads it as any other.

Everything read is checked before it is used, naming the file and the key: the record's entries
must be of their kinds, every floating-point weight finite, every int8 weight paired with its scales,
and the weights must fit the network the record describes, compared on torch's "meta" device before
any of it is allocated (a record claiming a billion IDs costs nothing).

The pattern record ties a checkpoint to the codebook its recognizer learned: loading with another
pattern (another codebook, or other marker appearance) is refused.  The fabric's extent (rows, cols,
origin) is not part of a marker's appearance and is not compared.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import pickle
import sys
from pathlib import Path

import numpy as np
import torch
from torch import nn

from assets.fileio import atomic_path
from assets.pattern import CropGeometry, PatternSpec, generate_codebook
from networks.config import TASKS, TrainConfig
from networks.tasks import build_model

FORMAT = "clothcapture-networks"
VERSION = 1
#: PatternSpec fields that say how large a fabric is, not what its markers look like
FABRIC_EXTENT_FIELDS = ("rows", "cols", "origin_xy")


@functools.lru_cache(maxsize=8)
def codebook_hash(spec: PatternSpec) -> str:
    """SHA-256 of the spec's whole codebook (num_ids, n, n) uint8: the IDs a recognizer learns."""
    return hashlib.sha256(np.ascontiguousarray(generate_codebook(spec), dtype=np.uint8).tobytes()).hexdigest()


def pattern_record(spec: PatternSpec) -> dict[str, object]:
    """{"spec": spec.to_dict(), "codebook_hash": ...}: what a checkpoint stores of its pattern."""
    return {"spec": spec.to_dict(), "codebook_hash": codebook_hash(spec)}


def checkpoint_spec(checkpoint: dict) -> PatternSpec:
    """The PatternSpec a checkpoint (as returned by `load_checkpoint`) was trained on."""
    return PatternSpec.from_dict(checkpoint["pattern"]["spec"], source="checkpoint pattern.spec")


def _plain(value: object) -> object:
    """Metrics as plain Python types (numpy scalars and arrays become floats and lists)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, torch.Tensor):
        return value.item() if value.numel() == 1 else value.tolist()
    return value


def save_checkpoint(
    path: str | Path,
    task: str,
    model: nn.Module,
    config: TrainConfig,
    spec: PatternSpec,
    optimizer: torch.optim.Optimizer | None = None,
    scheduler: torch.optim.lr_scheduler.LRScheduler | None = None,
    step: int = 0,
    metrics: dict | None = None,
    extra: dict | None = None,
) -> Path:
    """Write the checkpoint dict (module docstring) to `path` atomically; returns the path.

    extra: further plain entries (e.g. the best validation loss so far, the data source) stored at
    the top level; they may not replace the standard keys."""
    if task != config.task:
        raise ValueError(f"save_checkpoint: task {task!r} differs from config.task {config.task!r}")
    checkpoint = {
        "format": FORMAT,
        "version": VERSION,
        "task": task,
        "config": config.to_dict(),
        "pattern": pattern_record(spec),
        "crop_geometry": config.crop_geometry().to_dict(),
        "num_ids": int(spec.num_ids),
        "crosspoints_per_side": int(spec.crosspoints_per_side),
        "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "optimizer": optimizer.state_dict() if optimizer is not None else None,
        "scheduler": scheduler.state_dict() if scheduler is not None else None,
        "step": int(step),
        "metrics": _plain(metrics or {}),
        "rng": {"torch": torch.get_rng_state(),
                "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else []},
    }
    clash = sorted(set(extra or {}) & set(checkpoint))
    if clash:
        raise ValueError(f"save_checkpoint: extra entries {clash} would replace standard checkpoint keys")
    checkpoint.update(_plain(extra or {}))
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save(checkpoint, tmp)
    return path


def _describe(data: object) -> str:
    """What a loaded object that is not our checkpoint looks like, for the error message."""
    if isinstance(data, dict):
        keys = list(data)
        if keys and all(isinstance(v, torch.Tensor) for v in data.values()):
            resnet = {"conv1.weight", "bn1.weight", "layer1.0.conv1.weight"} <= set(keys)
            what = "a torchvision ResNet state dict (ImageNet weights? pass it as --pretrained)" if resnet \
                else "a bare state dict"
            return f"{what} with {len(keys)} tensors ({', '.join(map(str, keys[:3]))}, ...)"
        return f"a dict with keys {', '.join(map(str, keys[:8]))}" if keys else "an empty dict"
    return f"a {type(data).__name__}"


#: per task, the weights (key prefixes) a compact checkpoint keeps in float32: the localizer's head
#: regresses pixel offsets straight from its weights, and rounding it is what int8 cost the localizer
#: (held-out corners 0.45-0.48 -> 0.46-0.51 px, recall 0.989 -> 0.988), while rounding its backbone
#: even to 6 bits moved nothing; 1.8 MB more.
FLOAT_WEIGHTS = {"localizer": ("head.",), "recognizer": (), "crosspoints": ()}


def quantize_weights(state: dict[str, torch.Tensor], keep_float: tuple[str, ...] = (), bits: int = 8
                     ) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """(state with each floating-point weight of 2 or more dimensions as int8, {key: (out,) float32
    scale}).  Symmetric, per output channel (dim 0): the channel's largest magnitude maps to 127, so
    each weight moves by at most half its channel's step.  Other tensors (biases, normalisation
    parameters and statistics) and the weights whose key starts with one of `keep_float` stay
    float32: they are a few percent of a ResNet's bytes.  `bits` below 8 rounds coarser (still stored as
    int8), which magnifies what rounding costs."""
    levels = 2 ** (bits - 1) - 1
    stored, scales = {}, {}
    for key, value in state.items():
        if value.is_floating_point() and value.dim() >= 2 and not key.startswith(keep_float):
            weight = value.detach().float()
            scale = weight.abs().amax(dim=tuple(range(1, weight.dim()))).clamp_min(1e-12) / levels
            view = scale.view(-1, *[1] * (weight.dim() - 1))
            stored[key] = torch.round(weight / view).clamp(-levels, levels).to(torch.int8)
            scales[key] = scale
        else:
            stored[key] = value.detach().float() if value.is_floating_point() else value.detach()
    return stored, scales


def dequantize_weights(state: dict[str, torch.Tensor], scales: dict[str, torch.Tensor],
                       source: str = "checkpoint") -> dict[str, torch.Tensor]:
    """The float32 state dict of `quantize_weights`' output; a scale that fits no int8 weight is an error."""
    model = dict(state)
    for key, scale in scales.items():
        value = state.get(key)
        if value is None or value.dtype != torch.int8 or scale.shape != (value.shape[0],):
            raise ValueError(f"{source}: int8_scales[{key!r}] fits no int8 weight of that name")
        model[key] = value.float() * scale.float().view(-1, *[1] * (value.dim() - 1))
    return model


def read_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> dict:
    """The checkpoint dict at `path`, checked to be one of ours (format, version); no model built.
    A compact checkpoint's int8 weights come back as float32 ("int8_scales" stays, for the record)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such checkpoint file")
    try:
        data = torch.load(path, map_location=device, weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"{path}: not a checkpoint (torch.load with weights_only=True failed: {first})") from exc
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} checkpoint: it holds {_describe(data)}")
    if data.get("version") != VERSION:
        raise ValueError(f"{path}: checkpoint version {data.get('version')!r}, this code reads version {VERSION}")
    missing = [k for k in ("task", "config", "pattern", "num_ids", "crosspoints_per_side", "model", "step")
               if k not in data]
    if missing:
        raise ValueError(f"{path}: checkpoint lacks {', '.join(missing)}")
    _check_record(data, path)
    if data.get("int8_scales"):
        data["model"] = dequantize_weights(data["model"], data["int8_scales"], source=str(path))
    for key, value in data["model"].items():
        if value.is_floating_point() and not torch.isfinite(value).all():
            raise ValueError(f"{path}: model[{key!r}] holds non-finite values (NaN or inf)")
        if value.dtype == torch.int8:
            raise ValueError(f"{path}: model[{key!r}] is int8 without its scale in int8_scales")
    return data


def _check_record(data: dict, path: Path) -> None:
    """Raise ValueError naming `path` and the key for a checkpoint entry of the wrong kind."""
    if data["task"] not in TASKS:
        raise ValueError(f"{path}: task must be one of {', '.join(TASKS)}, got {data['task']!r}")
    pattern = data["pattern"]
    if not (isinstance(pattern, dict) and isinstance(pattern.get("spec"), dict)
            and isinstance(pattern.get("codebook_hash"), str)):
        raise ValueError(f"{path}: pattern must be {{'spec': a PatternSpec dict, 'codebook_hash': a string}}, "
                         f"got {_describe(pattern) if isinstance(pattern, dict) else repr(pattern)[:80]}")
    for key, least in (("num_ids", 1), ("crosspoints_per_side", 1), ("step", 0)):
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise ValueError(f"{path}: {key} must be an integer >= {least}, got {value!r}")
    for key in ("model", "int8_scales"):
        tensors = data.get(key) or {}
        if not isinstance(tensors, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor)
                                                    for k, v in tensors.items()):
            raise ValueError(f"{path}: {key} must map names to tensors, got {_describe(tensors)}")
    for key, scale in (data.get("int8_scales") or {}).items():
        if not scale.is_floating_point() or not (torch.isfinite(scale).all() and (scale > 0).all()):
            raise ValueError(f"{path}: int8_scales[{key!r}] must hold finite scales > 0")


def checkpoint_crop_geometry(checkpoint: dict, config: TrainConfig, source: str = "checkpoint") -> CropGeometry:
    """How a checkpoint's network cut its crops: its "crop_geometry", else (written before the record)
    the geometry its `config` trained with; a record whose jitter is not its config's is refused."""
    if checkpoint.get("crop_geometry") is None:
        return config.crop_geometry()
    geometry = CropGeometry.from_dict(checkpoint["crop_geometry"], source=f"{source}:crop_geometry")
    if geometry.jitter_px != config.crop_geometry().jitter_px:
        raise ValueError(f"{source}: crop_geometry.jitter_px is {geometry.jitter_px}, but its config trained with "
                         f"crop_jitter_px {config.crop_jitter_px}")
    return geometry


def check_pattern(checkpoint: dict, spec: PatternSpec, source: str = "checkpoint") -> None:
    """Raise ValueError when `spec`'s markers (appearance or codebook) differ from the checkpoint's."""
    saved = dict(checkpoint["pattern"]["spec"])
    given = spec.to_dict()
    differ = sorted(k for k in set(saved) | set(given)
                    if k not in FABRIC_EXTENT_FIELDS and _plain(saved.get(k)) != _plain(given.get(k)))
    if differ:
        detail = ", ".join(f"{k}: {saved.get(k)!r} vs {given.get(k)!r}" for k in differ)
        raise ValueError(f"{source}: trained on another pattern than the one given ({detail})")
    if checkpoint["pattern"].get("codebook_hash") != codebook_hash(spec):
        raise ValueError(f"{source}: trained on another codebook than the given pattern's (codebook_hash differs)")


def load_checkpoint(
    path: str | Path,
    expected_task: str | None = None,
    spec: PatternSpec | None = None,
    device: str | torch.device = "cpu",
) -> tuple[nn.Module, TrainConfig, dict]:
    """Rebuild the network stored at `path`: (model in eval mode on `device`, its TrainConfig, the
    checkpoint dict).  Raises FileNotFoundError for a missing file and ValueError, naming the file,
    for a file that is not one of our checkpoints, holds another task than `expected_task`, or was
    trained on another pattern than `spec` (when given)."""
    data = read_checkpoint(path, device)
    if expected_task is not None and data["task"] != expected_task:
        raise ValueError(f"{path}: a {data['task']} checkpoint, expected a {expected_task} checkpoint")
    config = TrainConfig.from_dict(data["config"], source=f"{path}:config")
    if config.task != data["task"]:
        raise ValueError(f"{path}: task {data['task']!r} but config.task {config.task!r}")
    if spec is not None:
        check_pattern(data, spec, source=str(path))
    modules_per_side = checkpoint_spec(data).modules_per_side  # a module reader's outputs
    crops = checkpoint_crop_geometry(data, config, str(path))

    def build() -> nn.Module:
        return build_model(data["task"], data["num_ids"], data["crosspoints_per_side"],
                           recognizer_classes=config.recognizer_classes, modules_per_side=modules_per_side,
                           crops=crops)

    with torch.device("meta"):  # the network's shapes, nothing allocated
        _check_fit(build().state_dict(), data["model"], f"{path}: the weights do not fit the {data['task']} network")
    model = build()
    model.load_state_dict(data["model"])
    return model.to(device).eval(), config, data


def _check_fit(expected: dict[str, torch.Tensor], given: dict[str, torch.Tensor], where: str) -> None:
    """Raise ValueError (`where`: ...) unless `given` has exactly `expected`'s keys and shapes, with a
    floating-point tensor wherever `expected` has one."""
    missing, unexpected = sorted(set(expected) - set(given)), sorted(set(given) - set(expected))
    if missing or unexpected:
        raise ValueError(f"{where}: missing {missing[:5]} ({len(missing)}), unexpected {unexpected[:5]} "
                         f"({len(unexpected)})")
    for key, value in expected.items():
        if given[key].shape != value.shape:
            raise ValueError(f"{where}: model[{key!r}] has shape {tuple(given[key].shape)}, the network's is "
                             f"{tuple(value.shape)}")
        if value.is_floating_point() and not given[key].is_floating_point():
            raise ValueError(f"{where}: model[{key!r}] is {given[key].dtype}, the network expects floating point")


def slim_checkpoint(source: str | Path, target: str | Path, dtype: torch.dtype | None = torch.bfloat16) -> Path:
    """Write `source` without its optimizer, scheduler and random states, its floating-point weights
    cast to `dtype` (None: kept; torch.int8: `quantize_weights`, a compact checkpoint, the task's
    `FLOAT_WEIGHTS` kept float32), to `target`
    (atomically); returns the target.

    A slim checkpoint is for inference (`load_checkpoint`, `networks.Detector`) and for starting a new
    run from it (`networks.train --init`); it cannot resume a run.  ResNet-50 weights in bf16 are
    about a quarter of a checkpoint with Adam's state in float32, in int8 an eighth."""
    data = read_checkpoint(source)
    scales: dict[str, torch.Tensor] = {}
    if dtype == torch.int8:
        model, scales = quantize_weights(data["model"], FLOAT_WEIGHTS.get(data["task"], ()))
    else:
        model = {k: v.to(dtype) if dtype is not None and v.is_floating_point() else v
                 for k, v in data["model"].items()}
    slim = {**data, "model": model, "optimizer": None, "scheduler": None, "int8_scales": scales,
            "rng": {"torch": torch.get_rng_state(), "cuda": []}}
    target = Path(target)
    with atomic_path(target) as tmp:
        torch.save(slim, tmp)
    return target


def main(argv: list[str] | None = None) -> int:
    from assets.cli import run_cli

    parser = argparse.ArgumentParser(prog="python -m networks.checkpoint", description="Checkpoint tools.")
    commands = parser.add_subparsers(dest="command", required=True)
    slim = commands.add_parser("slim", help="weights only, cast to bf16 (for inference and --init)")
    slim.add_argument("source", type=Path, help="a checkpoint (last.pt, best.pt)")
    slim.add_argument("target", type=Path, help="the slim checkpoint to write")
    kind = slim.add_mutually_exclusive_group()
    kind.add_argument("--keep-dtype", action="store_true", help="keep the weights' dtype (float32)")
    kind.add_argument("--int8", action="store_true",
                      help="weights as int8 per output channel (the localizer's head float32, FLOAT_WEIGHTS): "
                           "about half of bf16 (networks.weights stores these)")
    args = parser.parse_args(argv)

    def action() -> None:
        if args.source.resolve() == args.target.resolve():
            raise ValueError(f"{args.target}: would overwrite its source; name another file")
        dtype = None if args.keep_dtype else torch.int8 if args.int8 else torch.bfloat16
        out = slim_checkpoint(args.source, args.target, dtype)
        print(f"{out}: {out.stat().st_size / 2**20:.1f} MiB (from {args.source.stat().st_size / 2**20:.1f} MiB)")

    return run_cli(action)


if __name__ == "__main__":
    sys.exit(main())
