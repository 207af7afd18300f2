"""`python -m reconstruction detect` in the networks mode on the session's tiny capture, with real
(untrained, seeded) networks saved as checkpoints: the Detector gets the garment's marker tables and
the localizer scale from the run's settings."""

import json

import numpy as np
import pytest
import torch

from assets.garments import load_template
from networks.checkpoint import save_checkpoint
from networks.config import TrainConfig
from networks.detections import Detections
from networks.models import CrosspointLocalizer, MarkerLocalizer, MarkerRecognizer
from reconstruction.__main__ import build_parser, main

pytestmark = pytest.mark.slow  # the shared capture


def _checkpoints(folder, spec):
    """Untrained networks (as the CLI's --localizer PT --recognizer PT --crosspoints PT); the localizer's
    last layer is scaled down and biased so that every cell holds a 40 px marker, and the Detector has
    work downstream."""
    torch.manual_seed(0)
    localizer = MarkerLocalizer()
    with torch.no_grad():
        localizer.head.out.weight.mul_(0.01)
        layout = torch.tensor([[4, 4], [-16, -16], [24, -16], [-16, 24], [24, 24]], dtype=torch.float32)
        localizer.head.out.bias.copy_(torch.cat([torch.tensor([3.0]), layout.reshape(-1)]))
    models = {"localizer": localizer, "recognizer": MarkerRecognizer(spec.num_ids),
              "crosspoints": CrosspointLocalizer(crosspoints_per_side=spec.crosspoints_per_side)}
    paths = {task: save_checkpoint(folder / f"{task}.pt", task, model, TrainConfig(task=task), spec)
             for task, model in models.items()}
    return [arg for task, path in paths.items() for arg in (f"--{task}", str(path))]


def test_networks_mode_detects_with_the_garments_ids_at_the_localizer_scale(capture_folder, tmp_path):
    template = load_template(capture_folder / "template.npz")
    garment_ids = np.concatenate([t.marker_ids for t in template.layout.tables()])
    out = tmp_path / "rec"
    argv = ["detect", "--views", str(capture_folder), "--cameras", str(capture_folder / "cameras.json"),
            "--template", str(capture_folder / "template.npz"), "--out", str(out), "--device", "cpu",
            *_checkpoints(tmp_path, template.layout.spec), "--localizer-scale", "0.25",
            "--no-progress"]
    assert main(argv) == 0
    assert json.loads((out / "run.json").read_text())["localizer_scale"] == 0.25
    assert json.loads((out / "run.json").read_text())["grow_missing"] is True  # the default; --no-grow: False
    assert json.loads((out / "run.json").read_text())["smooth_crosspoints_px"] == 0.5  # the default
    cameras = [c["name"] for c in json.loads((capture_folder / "cameras.json").read_text())["cameras"]]
    found = []
    for camera in cameras:
        paths = sorted((out / "detections" / camera).iterdir())
        assert [p.name for p in paths] == ["f000003.npz", "f000004.npz"]
        found += [Detections.load(p) for p in paths]
    # 96 x 64 views at scale 0.25: the localizer sees 24 x 16 pixels, 3 x 2 cells, so at most 6 markers
    assert all(1 <= len(d) <= 6 for d in found)
    ids = np.concatenate([d.marker_id for d in found])
    assert np.isin(ids, garment_ids).all()  # the recognizer's answer is restricted to the garment's IDs
    k = template.layout.spec.crosspoints_per_side
    assert all(d.crosspoints_px.shape[1:] == (k, k, 2) for d in found)


def test_detection_sharded_over_devices_writes_what_one_device_writes(capture_folder, tmp_path):
    """--device cpu,cpu: the frames go to two spawned processes (as cuda:0,cuda:1 do on a GPU machine);
    the detections are those of one process, and a rerun keeps them."""
    template = capture_folder / "template.npz"
    checkpoints = _checkpoints(tmp_path, load_template(template).layout.spec)
    argv = ["detect", "--views", str(capture_folder), "--template", str(template), *checkpoints,
            "--localizer-scale", "0.25", "--no-progress"]
    assert main([*argv, "--device", "cpu", "--out", str(tmp_path / "one")]) == 0
    assert main([*argv, "--device", "cpu,cpu", "--out", str(tmp_path / "two")]) == 0
    one = sorted((tmp_path / "one" / "detections").glob("*/*.npz"))
    two = sorted((tmp_path / "two" / "detections").glob("*/*.npz"))
    assert len(one) >= 4 and [p.relative_to(tmp_path / "one") for p in one] == \
        [p.relative_to(tmp_path / "two") for p in two]
    for a, b in zip(one, two):
        first, second = Detections.load(a), Detections.load(b)
        assert np.array_equal(first.marker_id, second.marker_id)
        assert np.allclose(first.crosspoints_px, second.crosspoints_px, atol=1e-4)
    written = {p: p.stat().st_mtime_ns for p in two}
    assert main([*argv, "--device", "cpu,cpu", "--out", str(tmp_path / "two")]) == 0
    assert {p: p.stat().st_mtime_ns for p in two} == written  # nothing left to detect


def test_networks_mode_reads_the_cameras_of_a_capture_folder(capture_folder, tmp_path, capsys):
    """Without --cameras, the views folder's cameras.json (a factory capture's); a folder without one
    is refused, naming it."""
    template = capture_folder / "template.npz"
    checkpoints = _checkpoints(tmp_path, load_template(template).layout.spec)
    argv = ["detect", "--template", str(template), "--device", "cpu", *checkpoints,
            "--localizer-scale", "auto", "--frames", "3", "--no-progress"]
    assert main([*argv, "--views", str(capture_folder), "--out", str(tmp_path / "rec")]) == 0
    assert json.loads((tmp_path / "rec" / "run.json").read_text())["localizer_scale"] is None  # chosen per view
    cameras = json.loads((capture_folder / "cameras.json").read_text())["cameras"]
    assert [c["name"] for c in json.loads((tmp_path / "rec" / "detections" / "cameras.json").read_text())["cameras"]] \
        == [c["name"] for c in cameras]
    bare = tmp_path / "views"
    bare.mkdir()
    capsys.readouterr()
    assert main([*argv, "--views", str(bare), "--out", str(tmp_path / "rec2")]) != 0
    assert f"put cameras.json in {bare}" in capsys.readouterr().err


def test_run_evaluate_refuses_views_that_are_not_a_factory_capture_before_any_stage(tmp_path, capsys):
    views = tmp_path / "views"
    views.mkdir()
    (views / "cameras.json").write_text(json.dumps({"cameras": []}))
    checkpoints = [arg for task in ("localizer", "recognizer", "crosspoints") for arg in (f"--{task}", f"{task}.pt")]
    argv = ["run", "--views", str(views), "--template", "shirt", "--out", str(tmp_path / "rec"),
            *checkpoints, "--evaluate", "--no-progress"]
    assert main(argv) != 0
    assert "evaluating needs a factory capture" in capsys.readouterr().err
    assert not (tmp_path / "rec").exists()


def test_the_networks_are_named_one_flag_each_and_all_three_are_needed(tmp_path, capsys):
    """--localizer PT --recognizer PT --crosspoints PT (assets.cli's vocabulary) go to run.json in the
    Detector's order; one missing is refused naming it, before anything is written."""
    argv = ["detect", "--views", str(tmp_path), "--template", "shirt", "--out", str(tmp_path / "rec"),
            "--no-progress", "--crosspoints", str(tmp_path / "x.pt"), "--localizer", str(tmp_path / "l.pt")]
    assert main(argv) != 0
    assert "--recognizer missing" in capsys.readouterr().err
    assert not (tmp_path / "rec").exists()
    main(argv + ["--recognizer", str(tmp_path / "r.pt")])  # recorded, then no views to detect in
    recorded = json.loads((tmp_path / "rec" / "run.json").read_text())["checkpoints"]
    assert recorded == [str(tmp_path / name) for name in ("l.pt", "r.pt", "x.pt")]
    args = build_parser().parse_args(argv)
    assert not hasattr(args, "checkpoints") and not hasattr(args, "quiet") and args.no_progress


def _check_recorded_setting(tmp_path, field: str, default, other, bad: dict, match: str):
    """A RunSettings `field`: `default` unless given, `bad` refused (`match`), `other` written to run.json;
    a folder started with it refuses the default, naming the field and both values, and keeps its
    record; the same settings again reopen it."""
    from reconstruction import pipeline

    checkpoints = tuple(str(tmp_path / f"{task}.pt") for task in ("loc", "rec", "xp"))
    plain = pipeline.RunSettings(template="shirt", checkpoints=checkpoints)
    changed = pipeline.RunSettings(template="shirt", checkpoints=checkpoints, **{field: other})
    assert getattr(plain, field) == default
    with pytest.raises(ValueError, match=match):
        pipeline.RunSettings(template="shirt", checkpoints=checkpoints, **bad)
    pipeline.start(tmp_path / "new", changed)
    assert json.loads((tmp_path / "new" / "run.json").read_text())[field] == other
    refused = rf"run.json: .*other settings.*\({field}: {_json(other)} -> {_json(default)}\)"
    with pytest.raises(ValueError, match=refused):
        pipeline.start(tmp_path / "new", plain)
    assert pipeline.settings_of(tmp_path / "new") == changed
    pipeline.start(tmp_path / "new", changed)


def _json(value) -> str:
    return "\\(none\\)" if value is None else json.dumps(value)


def test_growth_is_a_recorded_setting(tmp_path):
    """`--no-grow` goes to run.json; a folder made with growth refuses a run without, and back."""
    _check_recorded_setting(tmp_path, "grow_missing", default=True, other=False,
                            bad={"level_mm": 0}, match="level_mm must be > 0")


def test_crosspoint_smoothing_is_a_recorded_setting(tmp_path):
    """The default 0.5 px and --no-smooth-crosspoints (None) go to run.json."""
    args = build_parser().parse_args(["detect", "--views", "v", "--template", "shirt", "--out", "o",
                                      "--no-smooth-crosspoints"])
    assert args.no_smooth_crosspoints and args.smooth_crosspoints == 0.5
    _check_recorded_setting(tmp_path, "smooth_crosspoints_px", default=0.5, other=None,
                            bad={"smooth_crosspoints_px": 0.0}, match="smooth_crosspoints_px must be in")


def test_keeping_cut_markers_own_points_is_a_recorded_setting(tmp_path):
    """The default 12 cells and --replace-own (None) go to run.json."""
    args = build_parser().parse_args(["detect", "--views", "v", "--template", "shirt", "--out", "o", "--replace-own"])
    assert args.replace_own and args.keep_own == 12.0
    _check_recorded_setting(tmp_path, "keep_own_cells", default=12.0, other=None,
                            bad={"keep_own_cells": 0.0}, match="keep_own_cells must be > 0 or None")


def test_the_neighbour_fit_is_a_recorded_setting(tmp_path):
    """--neighbour-fit WIDTH/DEGREE goes to run.json (default 1.5/2)."""
    def parse(*extra):
        return build_parser().parse_args(["detect", "--views", "v", "--template", "shirt", "--out", "o", *extra])

    assert parse().neighbour_fit == (1.5, 2) and parse("--neighbour-fit", "none/0").neighbour_fit == (None, 0)
    for bad in ("2", "0/2", "1/4", "x/1"):
        with pytest.raises(SystemExit):
            parse("--neighbour-fit", bad)
    _check_recorded_setting(tmp_path, "neighbour_degree", default=2, other=0,
                            bad={"neighbour_degree": 4}, match="degree in 0..3")
    _check_recorded_setting(tmp_path / "sigma", "neighbour_sigma_sides", default=1.5, other=None,
                            bad={"neighbour_sigma_sides": 0.0}, match="width > 0")


def test_a_folder_of_another_version_is_refused_by_the_settings_names(tmp_path):
    """A run.json naming a setting this version lacks (grow_rounds, since removed) or lacking one it has
    (grow_missing, since added) is refused by every stage, naming the setting: its outputs were made
    another way.  Removed options are gone from the CLI."""
    from reconstruction import pipeline

    for flag in ("--grow-rounds", "--crosspoint-shift"):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["detect", "--views", "v", "--template", "shirt", "--out", "o", flag, "2"])
    checkpoints = tuple(str(tmp_path / f"{task}.pt") for task in ("loc", "rec", "xp"))
    plain = pipeline.RunSettings(template="shirt", checkpoints=checkpoints)
    removed = pipeline.start(tmp_path / "removed", plain)
    record = json.loads((removed / "run.json").read_text())
    (removed / "run.json").write_text(json.dumps({**record, "grow_rounds": 1}))
    with pytest.raises(ValueError, match=r"run.json: unknown field\(s\) grow_rounds"):
        pipeline.settings_of(removed)
    with pytest.raises(ValueError, match=r"run.json: .*\(grow_rounds: 1 -> \(none\)\)"):
        pipeline.start(removed, plain)
    added = pipeline.start(tmp_path / "added", plain)
    del record["grow_missing"]
    (added / "run.json").write_text(json.dumps(record))
    with pytest.raises(ValueError, match=r"run.json: missing setting\(s\) grow_missing"):
        pipeline.triangulate(added)
    with pytest.raises(ValueError, match=r"run.json: .*\(grow_missing: \(none\) -> true\)"):
        pipeline.start(added, plain)
