"""Checkpoints and training configs: round trips through files, and the errors on wrong input."""

import dataclasses
import json

import pytest
import torch

from assets.pattern import CropGeometry, CropSpec, PatternSpec
from networks.backbone import resnet18
from networks.checkpoint import (checkpoint_spec, codebook_hash, load_checkpoint, read_checkpoint, save_checkpoint,
                                 slim_checkpoint)
from networks.checkpoint import main as checkpoint_main
from networks.config import TASK_DEFAULTS, TrainConfig
from networks.models import normalize
from networks.tasks import build_model, forward

SPEC = PatternSpec(rows=2, cols=2, num_ids=16)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A localizer after one real optimizer step, saved with optimizer and scheduler."""
    torch.manual_seed(0)
    config = TrainConfig("localizer", steps=10, batch_size=2, warmup_steps=0)
    model = build_model("localizer", SPEC.num_ids, SPEC.crosspoints_per_side)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: 1.0 - s / 10)
    batch = {"image": torch.randint(0, 256, (2, 3, 32, 32), dtype=torch.uint8),
             "cells": torch.zeros(2, 4, 4, 11)}
    _, loss, _ = forward("localizer", model, batch, torch.device("cpu"))
    loss.backward()
    optimizer.step()
    scheduler.step()
    path = tmp_path_factory.mktemp("ckpt") / "last.pt"
    save_checkpoint(path, "localizer", model, config, SPEC, optimizer, scheduler, step=1,
                    metrics={"loss": {"total": torch.tensor(0.5)}}, extra={"best_val_loss": 0.25})
    return path, model, config, batch


def test_round_trip_loads_with_weights_only(trained):
    path, model, config, batch = trained
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == "clothcapture-networks" and raw["version"] == 1 and raw["task"] == "localizer"
    assert raw["pattern"]["spec"] == SPEC.to_dict() and raw["pattern"]["codebook_hash"] == codebook_hash(SPEC)
    assert raw["num_ids"] == 16 and raw["step"] == 1 and raw["best_val_loss"] == 0.25
    assert raw["metrics"] == {"loss": {"total": 0.5}}
    assert raw["optimizer"]["state"] and raw["scheduler"]["last_epoch"] == 1
    loaded, loaded_config, record = load_checkpoint(path, expected_task="localizer", spec=SPEC)
    assert loaded_config == config and record["step"] == 1
    assert not loaded.training
    for key, value in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[key], value), key
    model.eval()
    with torch.no_grad():
        x = normalize(batch["image"])
        assert torch.equal(loaded(x), model(x))
    assert checkpoint_spec(record) == SPEC


def test_other_fabric_extent_is_the_same_pattern(trained):
    path = trained[0]
    load_checkpoint(path, spec=dataclasses.replace(SPEC, rows=3, cols=1, origin_xy=(0.5, 0.1)))


def test_wrong_task_and_pattern(trained):
    path = trained[0]
    with pytest.raises(ValueError, match="a localizer checkpoint, expected a recognizer"):
        load_checkpoint(path, expected_task="recognizer")
    with pytest.raises(ValueError, match="another pattern.*seed"):
        load_checkpoint(path, spec=dataclasses.replace(SPEC, seed=1))
    with pytest.raises(ValueError, match="another pattern.*code_rgb"):
        load_checkpoint(path, spec=dataclasses.replace(SPEC, code_rgb=(0, 0, 0)))


def test_wrong_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint at all" * 10)
    with pytest.raises(ValueError, match="junk.pt: not a checkpoint"):
        load_checkpoint(junk)
    resnet = tmp_path / "resnet18.pth"
    torch.save(resnet18(num_classes=1000).state_dict(), resnet)
    with pytest.raises(ValueError, match="resnet18.pth.*torchvision ResNet state dict"):
        read_checkpoint(resnet)
    listed = tmp_path / "list.pt"
    torch.save([1, 2, 3], listed)
    with pytest.raises(ValueError, match="holds a list"):
        load_checkpoint(listed)


def test_save_refuses_task_mismatch(tmp_path):
    model = build_model("localizer", SPEC.num_ids)
    with pytest.raises(ValueError, match="differs from config.task"):
        save_checkpoint(tmp_path / "x.pt", "localizer", model, TrainConfig("recognizer"), SPEC)
    assert not (tmp_path / "x.pt").exists()


def test_train_config_defaults_json_and_errors(tmp_path):
    for task, defaults in TASK_DEFAULTS.items():
        config = TrainConfig(task)
        assert config.batch_size == defaults["batch_size"] and config.steps == defaults["steps"]
        assert config.lr == 1e-4 and config.augment and config.mixed_precision
    assert TrainConfig("localizer").batch_size == 16 and TrainConfig("recognizer").batch_size == 256
    assert TrainConfig("crosspoints").batch_size == 64
    config = TrainConfig("crosspoints", steps=7, lr=3e-4, synth_weight=0.5)
    config.save(tmp_path / "c.json")
    assert TrainConfig.load(tmp_path / "c.json") == config
    assert config.replace(steps=None, batch_size=4).batch_size == 4
    with pytest.raises(ValueError, match="task must be one of"):
        TrainConfig("segmenter")
    with pytest.raises(ValueError, match="synth_weight must be in"):
        TrainConfig("localizer", synth_weight=1.5)
    with pytest.raises(ValueError, match="image_size must be a multiple of 8"):
        TrainConfig("localizer", image_size=100)
    (tmp_path / "bad.json").write_text(json.dumps({"task": "recognizer", "learning_rate": 1}))
    with pytest.raises(ValueError, match="bad.json: unknown field"):
        TrainConfig.load(tmp_path / "bad.json")
    (tmp_path / "bad2.json").write_text(json.dumps({"task": "recognizer", "steps": "many"}))
    with pytest.raises(ValueError, match="bad2.json.*steps must be an integer"):
        TrainConfig.load(tmp_path / "bad2.json")


def test_slim_checkpoint_keeps_the_network_in_bf16_without_the_optimizer(trained, tmp_path, capsys):
    path, model, config, batch = trained
    slim = slim_checkpoint(path, tmp_path / "slim.pt")
    data = read_checkpoint(slim)
    assert data["optimizer"] is None and data["scheduler"] is None and data["step"] == 1
    assert data["best_val_loss"] == 0.25 and data["config"] == config.to_dict()
    floats = [v for v in data["model"].values() if v.is_floating_point()]
    assert floats and all(v.dtype == torch.bfloat16 for v in floats)
    assert data["model"]["backbone.bn1.num_batches_tracked"].dtype == torch.int64
    assert slim.stat().st_size < path.stat().st_size / 3  # no Adam moments, half the bytes per weight
    loaded, _, _ = load_checkpoint(slim, expected_task="localizer", spec=SPEC)
    model.eval()
    with torch.no_grad():
        x = normalize(batch["image"])
        assert torch.allclose(loaded(x), model(x), rtol=0.05, atol=0.05)  # bf16 weights, float32 maths
    kept = slim_checkpoint(path, tmp_path / "kept.pt", dtype=None)
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in read_checkpoint(kept)["model"].items())
    assert checkpoint_main(["slim", str(path), str(tmp_path / "cli.pt")]) == 0
    assert "cli.pt" in capsys.readouterr().out and (tmp_path / "cli.pt").is_file()
    assert checkpoint_main(["slim", str(path), str(path)]) != 0  # never over its source
    assert "overwrite its source" in capsys.readouterr().err and read_checkpoint(path)["optimizer"] is not None
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt: not a checkpoint"):
        slim_checkpoint(tmp_path / "junk.pt", tmp_path / "out.pt")
    assert not (tmp_path / "out.pt").exists()


def test_checkpoints_carry_the_crop_geometry_the_network_cuts_with(tmp_path):
    """A crop network's checkpoint records its crops and jitter; the rebuilt network carries them (what the
    Detector cuts with).  A checkpoint written before the record loads with its config's; a record that
    contradicts its config is refused by name."""
    config = TrainConfig("crosspoints", crop_jitter_px=1.0)
    model = build_model("crosspoints", SPEC.num_ids, SPEC.crosspoints_per_side, crops=config.crop_geometry())
    path = save_checkpoint(tmp_path / "xp.pt", "crosspoints", model, config, SPEC)
    raw = torch.load(path, weights_only=True)
    assert raw["crop_geometry"] == {"recognizer": {"size_px": 96, "margin_cells": 0},
                                    "crosspoints": {"size_px": 112, "margin_cells": 2}, "jitter_px": 1.0}
    loaded, _, _ = load_checkpoint(path)
    assert loaded.crops == CropGeometry(jitter_px=1.0) and loaded.crop == CropSpec(112, 2)
    del raw["crop_geometry"]  # as written before the record
    torch.save(raw, tmp_path / "old.pt")
    assert load_checkpoint(tmp_path / "old.pt")[0].crops == CropGeometry(jitter_px=1.0)
    torch.save({**raw, "crop_geometry": CropGeometry(jitter_px=2.0).to_dict()}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match=r"other\.pt: crop_geometry\.jitter_px is 2\.0, but its config trained with "
                                         r"crop_jitter_px 1\.0"):
        load_checkpoint(tmp_path / "other.pt")
    torch.save({**raw, "crop_geometry": {"recognizer": {"size_px": "96"}}}, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match=r"bad\.pt:crop_geometry: missing field\(s\) crosspoints, jitter_px"):
        load_checkpoint(tmp_path / "bad.pt")
    assert TrainConfig("localizer", crop_jitter_px=1.0).crop_geometry() == CropGeometry()  # it cuts no crops
