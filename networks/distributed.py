"""Training on several processes (GPUs, or CPU processes) with torch's DistributedDataParallel.

    torchrun --nproc-per-node 2 -m networks.train localizer --data out/ds --out runs/loc

`torchrun` starts one process per rank and sets RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR and
MASTER_PORT; `Ranks.from_environment` reads them (without them: one process, nothing changes).
NCCL carries the collectives between GPUs (rank r trains on cuda:LOCAL_RANK), gloo between CPU
processes.  `TrainConfig.batch_size` is the global batch: step s of the run is positions
s * B .. (s + 1) * B - 1 of `networks.train.StepOrder` for any number of ranks, and rank r takes the
r-th of its W equal, consecutive shares (`RankBatches`), so the ranks' shares put together in rank
order are the single-process batch and a resumed run sees the same batches.

BatchNorm: every rank would normalise with the statistics of its own share, not of the global batch.
So with W > 1 the BatchNorm layers become `torch.nn.SyncBatchNorm` on GPUs and `GlobalBatchNorm` on
the CPU (torch's SyncBatchNorm refuses CPU tensors: "SyncBatchNorm expected input tensor to be on GPU",
torch 2.11 and 2.13); both normalise with the global batch's statistics and keep the state-dict keys.
Losses that are means over the batch (cross-entropy, the BCE terms) then give the single-process
gradients up to floating-point reduction order.  The localizer's point MSE and the crosspoints' xy MSE
are normalised by the number of valid targets: under DDP by the mean over the ranks of their counts
(`count_mean` of `networks.models.localizer_loss` / `crosspoint_loss`, passed by `networks.train`), so
that the ranks' averaged gradients are those of the global batch's MSE.
"""

from __future__ import annotations

import datetime
import os
from dataclasses import dataclass
from typing import Iterator

import torch
import torch.distributed as dist
from torch import nn
from torch.utils.data import Sampler

#: how long a rank waits for the others (validation and checkpoints run on rank 0 while they wait)
TIMEOUT = datetime.timedelta(hours=1)


@dataclass(frozen=True)
class Ranks:
    """This process's place among the training processes: rank (0 .. world_size - 1) and local_rank
    (its GPU on this machine)."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        """Rank 0 writes checkpoints, logs and the progress bar."""
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @classmethod
    def from_environment(cls) -> "Ranks":
        """From torchrun's RANK, WORLD_SIZE and LOCAL_RANK; one process when they are unset."""
        if "RANK" not in os.environ or "WORLD_SIZE" not in os.environ:
            return cls()
        try:
            rank, world = int(os.environ["RANK"]), int(os.environ["WORLD_SIZE"])
            local = int(os.environ.get("LOCAL_RANK", rank))
        except ValueError as exc:
            raise ValueError(f"RANK, WORLD_SIZE and LOCAL_RANK must be integers ({exc})") from exc
        if not 0 <= rank < world:
            raise ValueError(f"RANK {rank} is outside 0..{world - 1} (WORLD_SIZE {world})")
        return cls(rank, world, local)

    def share(self, batch_size: int) -> int:
        """Samples per rank of a global batch of `batch_size`."""
        if batch_size % self.world_size:
            raise ValueError(f"batch_size {batch_size} (the global batch) must be a multiple of the number of "
                             f"processes, {self.world_size}")
        return batch_size // self.world_size


def rank_device(ranks: Ranks, device: torch.device) -> torch.device:
    """The device of this rank: cuda:LOCAL_RANK when `device` is a CUDA device of several ranks."""
    if ranks.distributed and device.type == "cuda":
        return torch.device("cuda", ranks.local_rank)
    return device


def join(ranks: Ranks, device: torch.device) -> bool:
    """Join the process group of the ranks (NCCL on CUDA, gloo otherwise); whether it joined one (not
    for one process, nor when the caller has joined one already)."""
    if not ranks.distributed or dist.is_initialized():
        return False
    if device.type == "cuda":
        torch.cuda.set_device(device)
        dist.init_process_group("nccl", rank=ranks.rank, world_size=ranks.world_size, timeout=TIMEOUT,
                                device_id=device)
    else:
        dist.init_process_group("gloo", rank=ranks.rank, world_size=ranks.world_size, timeout=TIMEOUT)
    return True


def leave() -> None:
    """Leave the process group that `join` joined."""
    if dist.is_initialized():
        dist.destroy_process_group()


class RankBatches(Sampler):
    """Rank `rank`'s share of the global batches of steps `first` .. `last` - 1: for step s the
    positions s * B + rank * b .. s * B + (rank + 1) * b - 1 (B the global batch, b = B / world_size)."""

    def __init__(self, first: int, last: int, batch_size: int, ranks: Ranks):
        self.first, self.last, self.batch_size = first, last, batch_size
        self.share = ranks.share(batch_size)
        self.offset = ranks.rank * self.share

    def __len__(self) -> int:
        return max(0, self.last - self.first)

    def __iter__(self) -> Iterator[list[int]]:
        for step in range(self.first, self.last):
            start_at = step * self.batch_size + self.offset
            yield list(range(start_at, start_at + self.share))


class _SumOverRanks(torch.autograd.Function):
    """The sum of a tensor over the ranks, differentiable: the gradient is the sum of the ranks' gradients
    (the global loss is the sum of theirs)."""

    @staticmethod
    def forward(ctx, tensor: torch.Tensor, group) -> torch.Tensor:
        ctx.group = group
        total = tensor.clone()
        dist.all_reduce(total, group=group)
        return total

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None]:
        total = grad.clone()
        dist.all_reduce(total, group=ctx.group)
        return total, None


class GlobalBatchNorm(nn.BatchNorm2d):
    """`nn.BatchNorm2d` that, training in a process group of several ranks, normalises with the mean and
    (biased) variance of the global batch: sums over the ranks by differentiable all-reduces, so the
    gradients are those of the global batch too.  Works on every backend (gloo on the CPU, where
    `torch.nn.SyncBatchNorm` does not).  Every rank must hold equal shares (`RankBatches`).  The
    statistics are summed in float64, as CPU BatchNorm accumulates them.  In eval mode, or alone, it
    is BatchNorm2d."""

    group = None  # the process group of the statistics (None: the default one)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (self.training and dist.is_initialized() and dist.get_world_size(self.group) > 1):
            return super().forward(x)
        self._check_input_dim(x)
        count = x.numel() // x.shape[1] * dist.get_world_size(self.group)
        dims = (0, 2, 3)
        mean = _SumOverRanks.apply(x.double().sum(dims), self.group) / count
        centred = x - mean.to(x.dtype)[None, :, None, None]
        var = _SumOverRanks.apply(centred.double().square().sum(dims), self.group) / count
        scale = torch.rsqrt(var + self.eps).to(x.dtype)
        if self.affine:
            scale = scale * self.weight
        y = centred * scale[None, :, None, None]
        if self.affine:
            y = y + self.bias[None, :, None, None]
        if self.track_running_stats:
            with torch.no_grad():
                self.num_batches_tracked += 1
                factor = 1.0 / float(self.num_batches_tracked) if self.momentum is None else self.momentum
                self.running_mean.lerp_(mean.to(self.running_mean.dtype), factor)
                unbiased = var * (count / max(1, count - 1))
                self.running_var.lerp_(unbiased.to(self.running_var.dtype), factor)
        return y


def convert_global_batchnorm(module: nn.Module, group=None) -> nn.Module:
    """`module` with every BatchNorm2d replaced by a `GlobalBatchNorm` holding the same parameters and
    buffers (the state-dict keys stay)."""
    if isinstance(module, nn.BatchNorm2d) and not isinstance(module, GlobalBatchNorm):
        converted = GlobalBatchNorm(module.num_features, module.eps, module.momentum, module.affine,
                                    module.track_running_stats, device=module.weight.device if module.affine else None)
        converted.group = group
        if module.affine:
            converted.weight, converted.bias = module.weight, module.bias
        if module.track_running_stats:
            converted.running_mean, converted.running_var = module.running_mean, module.running_var
            converted.num_batches_tracked = module.num_batches_tracked
        converted.train(module.training)
        return converted
    for name, child in module.named_children():
        module.add_module(name, convert_global_batchnorm(child, group))
    return module


def parallel(model: nn.Module, ranks: Ranks, device: torch.device) -> nn.Module:
    """`model` (on `device`) wrapped for training on the ranks: its BatchNorm layers normalising with the
    global batch (SyncBatchNorm on CUDA, `GlobalBatchNorm` elsewhere) inside DistributedDataParallel.
    One process: `model` itself."""
    if not ranks.distributed:
        return model
    if device.type == "cuda":
        model = nn.SyncBatchNorm.convert_sync_batchnorm(model)
        return nn.parallel.DistributedDataParallel(model, device_ids=[device.index], output_device=device.index)
    model = convert_global_batchnorm(model, dist.new_group(backend="gloo"))
    return nn.parallel.DistributedDataParallel(model)


def mean_over_ranks(values: torch.Tensor, ranks: Ranks) -> torch.Tensor:
    """The mean over the ranks of `values` (every rank gets it); `values` itself for one process."""
    if not ranks.distributed:
        return values
    values = values.clone()
    dist.all_reduce(values)
    return values / ranks.world_size


def any_rank(flag: bool, ranks: Ranks, device: torch.device) -> bool:
    """Whether `flag` holds on some rank (every rank gets the same answer)."""
    if not ranks.distributed:
        return flag
    value = torch.tensor([1.0 if flag else 0.0], device=device)
    dist.all_reduce(value)
    return bool(value.item() > 0)
