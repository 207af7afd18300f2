"""Training on several processes: a 2-process gloo run through torchrun sees the single-process
batches, losses and BatchNorm statistics, and only rank 0 writes the run folder; `GlobalBatchNorm`
under DistributedDataParallel gives the single-process gradients."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from torch import nn

from networks.distributed import RankBatches, Ranks, convert_global_batchnorm
from networks.train import train
from tests.networks.test_evaluate import write_factory_dataset
from tests.networks.test_train import SPEC, _config, _losses

PROJECT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_rank_batches_share_the_global_batch():
    shares = [list(RankBatches(3, 5, 6, Ranks(r, 3))) for r in range(3)]
    assert [sum((s[k] for s in shares), []) for k in range(2)] == [list(range(18, 24)), list(range(24, 30))]
    assert list(RankBatches(3, 5, 6, Ranks())) == [list(range(18, 24)), list(range(24, 30))]
    with pytest.raises(ValueError, match="multiple of the number of processes, 4"):
        Ranks(0, 4).share(6)


def _net() -> nn.Module:
    torch.manual_seed(0)
    return nn.Sequential(nn.Conv2d(3, 4, 3), nn.BatchNorm2d(4), nn.ReLU(inplace=True), nn.Conv2d(4, 2, 3),
                         nn.BatchNorm2d(2))


def _batch() -> tuple[torch.Tensor, torch.Tensor]:
    return (torch.randn(4, 3, 8, 8, generator=torch.Generator().manual_seed(2)),
            torch.randn(4, 2, 4, 4, generator=torch.Generator().manual_seed(3)))


def _loss(model: nn.Module, x: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    return ((model(x) - target) ** 2).mean()


def _rank(rank: int, port: int, out: str) -> None:
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank, world_size=2)
    try:
        model = convert_global_batchnorm(_net(), dist.new_group(backend="gloo"))
        x, target = (t[2 * rank:2 * rank + 2] for t in _batch())
        wrapped = nn.parallel.DistributedDataParallel(model)  # kept: its hooks average the gradients
        _loss(wrapped, x, target).backward()
        if rank == 0:
            torch.save({"grad": {n: p.grad for n, p in model.named_parameters()}, "state": model.state_dict()}, out)
    finally:
        dist.destroy_process_group()


def test_global_batchnorm_gives_single_process_gradients(tmp_path):
    out = tmp_path / "rank0.pt"
    mp.spawn(_rank, args=(_free_port(), str(out)), nprocs=2)
    model = _net()
    _loss(model, *_batch()).backward()
    ranked = torch.load(out, weights_only=True)
    for name, p in model.named_parameters():
        if name.endswith("0.bias") or name == "3.bias":  # a bias before BatchNorm: its gradient is 0 up to rounding
            continue
        torch.testing.assert_close(ranked["grad"][name], p.grad, rtol=1e-5, atol=1e-7)
    for name, value in model.state_dict().items():  # running statistics of the global batch
        torch.testing.assert_close(ranked["state"][name], value, rtol=1e-5, atol=1e-7)


def test_torchrun_two_processes_match_one(tmp_path):
    # the recognizer's loss is a mean over the batch: the global batch's gradients are the mean of the
    # ranks'.  Its ResNet-50 on 96 px crops in batches of 4 is badly conditioned (float32 against float64
    # changes its gradients by ~2 %), and Adam's first steps are sign-like, so the runs are compared
    # where rounding cannot grow: the first step's loss (the global-batch BatchNorm forward)
    data = write_factory_dataset(tmp_path / "ds", SPEC, {"train": 2, "val": 1})
    config = _config("recognizer", steps=2, batch_size=4)
    train(config, data, tmp_path / "one", device="cpu", spec=SPEC, progress=False)
    config.save(tmp_path / "config.json")
    SPEC.save(tmp_path / "pattern.json")
    command = [sys.executable, "-m", "torch.distributed.run", "--nnodes", "1", "--nproc-per-node", "2",
               "--rdzv-backend", "c10d", "--rdzv-endpoint", f"127.0.0.1:{_free_port()}",
               "-m", "networks.train", "recognizer", "--data", str(data), "--out", str(tmp_path / "two"),
               "--config", str(tmp_path / "config.json"), "--pattern", str(tmp_path / "pattern.json"),
               "--device", "cpu", "--no-progress"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(PROJECT)}
    done = subprocess.run(command, cwd=PROJECT, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("recognizer: finished at step 2 of 2") == 1  # rank 0 speaks for both
    one, two = _losses(tmp_path / "one"), _losses(tmp_path / "two")
    assert sorted(two) == [1, 2]  # one line per step: rank 0 alone writes the log
    assert two[1] == pytest.approx(one[1], rel=1e-5)
    assert sorted(p.name for p in (tmp_path / "two").iterdir()) == ["best.pt", "config.json", "last.pt", "log.jsonl"]
    lines = [json.loads(line) for line in (tmp_path / "two" / "log.jsonl").read_text().splitlines()]
    assert sum("val" in r for r in lines) == 1
    saved = torch.load(tmp_path / "two" / "last.pt", weights_only=True)
    assert saved["step"] == 2 and set(saved["model"]) == set(torch.load(tmp_path / "one" / "last.pt",
                                                                          weights_only=True)["model"])


@pytest.mark.parametrize("task", ["localizer", "crosspoints"])
def test_mse_over_the_global_count_makes_rank_gradients_average_to_the_single_process_ones(task):
    """Two ranks with different numbers of valid targets: each divides its squared error by the mean
    of the ranks' counts (what `networks.train` passes under DDP), so the mean of their losses and
    gradients, which DDP takes, is the whole batch's."""
    from networks.models import crosspoint_loss, localizer_loss

    torch.manual_seed(0)
    if task == "localizer":
        output = torch.randn(4, 11, 3, 5, requires_grad=True)
        cells = torch.randn(4, 3, 5, 11)
        cells[..., 0] = (torch.rand(4, 3, 5) < torch.tensor([0.9, 0.8, 0.2, 0.1])[:, None, None]).float()
        cells[0, 0, 0, 3:5] = float("nan")  # a point off the fabric
        loss_of = lambda out, rows, count_mean=None: localizer_loss(out, cells[rows], count_mean=count_mean)[0]  # noqa: E731
    else:
        output = torch.randn(4, 3, 25, 25, requires_grad=True)
        xy = 112 * torch.rand(4, 25, 25, 2)
        visible = torch.rand(4, 25, 25) < torch.tensor([0.9, 0.7, 0.3, 0.1])[:, None, None]
        loss_of = lambda out, rows, count_mean=None: crosspoint_loss(out, xy[rows], visible[rows],  # noqa: E731
                                                                     count_mean=count_mean)[0]
    whole = loss_of(output, slice(0, 4))
    (expected,) = torch.autograd.grad(whole, output)
    # the ranks' counts, as the losses count them, and their mean (the all-reduce of `mean_over_ranks`)
    counts = []
    for rows in (slice(0, 2), slice(2, 4)):
        loss_of(output[rows], rows, count_mean=lambda c: counts.append(c.clone()) or c)
    mean = lambda c: (counts[0] + counts[1]) / 2  # noqa: E731
    assert not torch.equal(counts[0], counts[1])  # the case a per-rank count would get wrong
    shares = [loss_of(output[rows], rows, count_mean=mean) for rows in (slice(0, 2), slice(2, 4))]
    averaged = (shares[0] + shares[1]) / 2
    (gradient,) = torch.autograd.grad(averaged, output)
    assert averaged.item() == pytest.approx(whole.item(), rel=1e-6)
    torch.testing.assert_close(gradient, expected, rtol=1e-5, atol=1e-7)
