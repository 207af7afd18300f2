"""What each of the three training tasks is: its network, how a batch goes in, and its loss.

The one place where "localizer", "recognizer" and "crosspoints" differ for training and evaluation;
the loops in `networks.train` and `networks.evaluate` are the same for all three.  Batches are the
collated dataset items of `networks.data` (uint8 images and crops, float32 targets):

  localizer:   image (B, 3, H, W) uint8, cells (B, H/8, W/8, 11) float32
  recognizer:  crop (B, 3, 96, 96) uint8, marker_id (B,) int64 (a module reader's targets are the IDs'
               module grids, looked up in the codebook's `networks.codes.module_targets`)
  crosspoints: crop, reference (B, 3, 112, 112) uint8, xy (B, 25, 25, 2) float32, visible (B, 25, 25) bool
"""

from __future__ import annotations

import contextlib

import torch
from torch import nn

from assets.pattern import CropGeometry
from networks.config import TASKS
from networks.models import (
    CrosspointLocalizer,
    MarkerLocalizer,
    MarkerModuleReader,
    MarkerRecognizer,
    crosspoint_loss,
    localizer_loss,
    module_loss,
    normalize,
    recognizer_loss,
)

#: the batch entries each task needs
BATCH_KEYS = {
    "localizer": ("image", "cells"),
    "recognizer": ("crop", "marker_id"),
    "crosspoints": ("crop", "reference", "xy", "visible"),
}


def build_model(task: str, num_ids: int, crosspoints_per_side: int = 25, pretrained: str | None = None,
                recognizer_classes: str = "garment", modules_per_side: int = 12,
                crops: CropGeometry = CropGeometry()) -> nn.Module:
    """The untrained network of `task`; `pretrained` is a torchvision ImageNet ResNet state-dict file;
    crops: how the crop networks' crops are cut (`TrainConfig.crop_geometry`, a checkpoint's record),
    which they carry; recognizer_classes "modules"
    (`TrainConfig.recognizer_classes`): the recognizer is a `MarkerModuleReader` of the pattern's
    `modules_per_side`, otherwise a `MarkerRecognizer` of `num_ids` classes."""
    if task == "localizer":
        return MarkerLocalizer(pretrained=pretrained)
    if task == "recognizer" and recognizer_classes == "modules":
        return MarkerModuleReader(modules_per_side, pretrained=pretrained, crops=crops)
    if task == "recognizer":
        return MarkerRecognizer(num_ids, pretrained=pretrained, crops=crops)
    if task == "crosspoints":
        return CrosspointLocalizer(pretrained=pretrained, crosspoints_per_side=crosspoints_per_side, crops=crops)
    raise ValueError(f"unknown task {task!r}: expected one of {', '.join(TASKS)}")


def reads_modules(model: nn.Module) -> bool:
    """Whether a recognizer outputs code-module logits (`MarkerModuleReader`, or one wrapped by
    DistributedDataParallel) rather than ID logits."""
    return isinstance(getattr(model, "module", model), MarkerModuleReader)


def autocast(device: torch.device, enabled: bool) -> contextlib.AbstractContextManager:
    """bf16 autocast on CUDA when `enabled`; a no-op elsewhere (CPU runs in float32)."""
    if enabled and device.type == "cuda":
        return torch.autocast("cuda", dtype=torch.bfloat16)
    return contextlib.nullcontext()


def batch_length(batch: dict[str, torch.Tensor]) -> int:
    """Number of samples in a collated batch."""
    return len(next(iter(batch.values())))


def forward(task: str, model: nn.Module, batch: dict[str, torch.Tensor], device: torch.device, count_mean=None,
            codes: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
    """Run `model` on a batch: (raw output, loss scalar, {loss part: detached scalar}); `count_mean`:
    under DDP, the mean over the ranks of the losses' target counts (see `localizer_loss`);
    `codes`: for a module-reading recognizer (`reads_modules`), the codebook's module grids
    (num_ids, n * n) {0, 1} (`networks.codes.module_targets`), whose rows of the batch's IDs are the
    targets of `module_loss`.

    Images travel to the device as uint8 and are normalised there; the loss is computed in float32
    on the output (which may be bf16 under autocast)."""
    missing = [k for k in BATCH_KEYS[task] if k not in batch]
    if missing:
        raise ValueError(f"{task} batch lacks {', '.join(missing)} (has {', '.join(batch)})")
    get = {k: batch[k].to(device, non_blocking=True) for k in BATCH_KEYS[task]}
    if task == "localizer":
        output = model(normalize(get["image"]))
        loss, parts = localizer_loss(output.float(), get["cells"], count_mean=count_mean)
    elif task == "recognizer" and reads_modules(model):
        if codes is None:
            raise ValueError("forward: a module-reading recognizer needs the codebook's module grids (codes)")
        output = model(normalize(get["crop"]))
        loss = module_loss(output.float(), codes.to(device)[get["marker_id"].long()])
        parts = {"module_bce": loss.detach()}
    elif task == "recognizer":
        output = model(normalize(get["crop"]))
        loss = recognizer_loss(output.float(), get["marker_id"])
        parts = {"cross_entropy": loss.detach()}
    else:
        output = model(normalize(get["crop"]), normalize(get["reference"]))
        loss, parts = crosspoint_loss(output.float(), get["xy"], get["visible"], count_mean)
    return output, loss, parts
