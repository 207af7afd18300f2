"""`benchmarks/train_networks.py`: the GPU placement of its runs (which GPU each training process gets), its
run table for one call, its evaluation stages kept apart, and the presence threshold chosen on one
split by F1 and checked on another."""

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

PROJECT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("train_networks")


MAIN3 = ["localizer_mix", "recognizer_partial", "crosspoints_rendered"]


def test_no_gpu_is_one_process_each(bench):
    assert bench.placement(MAIN3, 0) == {name: [] for name in MAIN3}


def test_one_gpu_is_shared(bench):
    assert bench.placement(MAIN3 + ["recognizer"], 1) == {name: [0] for name in MAIN3 + ["recognizer"]}


def test_two_gpus_give_the_crosspoint_run_one_to_itself(bench):
    placed = bench.placement(MAIN3, 2)
    assert placed["crosspoints_rendered"] == [0]
    assert placed["recognizer_partial"] == placed["localizer_mix"] == [1]
    assert list(placed) == MAIN3  # the caller's order


def test_comparison_runs_take_the_least_loaded_gpu_and_spare_gpus_join_the_heaviest(bench):
    placed = bench.placement(MAIN3 + ["localizer_synth"], 3)
    assert sorted(g for name in MAIN3 for g in placed[name]) == [0, 1, 2]
    assert placed["localizer_synth"] == placed["localizer_mix"] == [2]  # the lightest main run's GPU
    fourth = bench.placement(MAIN3 + ["crosspoints"], 4)
    assert fourth["crosspoints"] == [3] and fourth["crosspoints_rendered"] == [0]  # no spare GPU is left
    assert bench.placement(MAIN3 + ["crosspoints", "recognizer"], 4)["recognizer"] == [2]
    spare = bench.placement(MAIN3, 5)
    assert spare["crosspoints_rendered"] == [0, 3] and spare["recognizer_partial"] == [1, 4]
    assert spare["localizer_mix"] == [2]


def test_runs_sharing_a_gpu_are_named_in_the_log(bench):
    note = bench.sharing_note(bench.placement(MAIN3 + ["localizer_upright", "recognizer_small"], 4))
    assert note.startswith("note: 5 runs on 4 GPUs") and "(GPU 2: localizer_mix, recognizer_small)" in note
    assert bench.sharing_note(bench.placement(MAIN3 + ["localizer_upright"], 4)) == ""
    assert bench.sharing_note(bench.placement(MAIN3, 0)) == ""  # the CPU: one run after another


def test_a_run_s_synth_weight_can_be_changed_for_one_call(bench):
    runs = bench.with_synth_weight(bench.RUNS, "localizer_mix", 0.5)
    assert runs["localizer_mix"][1] == 0.5 and bench.RUNS["localizer_mix"][1] == 0.0  # a new table
    assert {k: v for k, v in runs.items() if k != "localizer_mix"} == {
        k: v for k, v in bench.RUNS.items() if k != "localizer_mix"}
    assert runs["localizer_mix"][::2] == bench.RUNS["localizer_mix"][::2]  # task, stop and shards kept
    with pytest.raises(ValueError, match="synth weight"):
        bench.with_synth_weight(bench.RUNS, "localizer_mix", 1.5)


def test_synth_weight_sets_any_run_s_share_for_one_call_and_refuses_bad_items(bench):
    runs = bench.synth_weights(["crosspoints_jitter=0", "recognizer_partial=0.75"], bench.RUNS)
    assert runs["crosspoints_jitter"][1] == 0.0 and runs["recognizer_partial"][1] == 0.75
    assert bench.RUNS["crosspoints_jitter"][1] == 0.75 and bench.RUNS["recognizer_partial"][1] == 0.25  # a new table
    assert bench.synth_weights([], bench.RUNS) == bench.RUNS
    for item, problem in (("crosspoints_jitter", "RUN=W"), ("nope=0.5", "RUN=W"),
                          ("crosspoints_jitter=x", "not a number"), ("crosspoints_jitter=2", "synth weight")):
        with pytest.raises(ValueError, match=problem):
            bench.synth_weights([item], bench.RUNS)


def test_a_failing_stage_is_recorded_and_the_next_still_runs(bench, tmp_path):
    result = {"errors": {}}
    path = tmp_path / "results.json"
    stage = bench.Stages(result, path, started=0.0)
    assert json.loads(path.read_text())["errors"] == {}  # written before the first stage
    stage("detector", lambda: 1 / 0)
    stage("throughput", lambda rows: rows + [{"images_per_s": 2.0}], [])
    saved = json.loads(path.read_text())
    assert "ZeroDivisionError" in saved["errors"]["detector"] and "detector" not in saved
    assert saved["throughput"] == [{"images_per_s": 2.0}] and saved["wall_s"] > 0


def test_prepare_builds_the_samples_a_dataset_travelled_without_on_several_cores(bench, tmp_path):
    from assets.fileio import load_npz, save_npz
    from assets.pattern import PatternSpec
    from tests.networks.test_evaluate import write_factory_dataset

    spec = PatternSpec(rows=4, cols=4)
    built = write_factory_dataset(tmp_path / "built", spec, {"train": 2, "val": 1, "test": 1})
    layout = {"spec": spec.to_dict(), "panels": []}
    save_npz(built / "template.npz", {"layout_json": np.frombuffer(json.dumps(layout).encode(), np.uint8)})
    travelled = tmp_path / "travelled"
    shutil.copytree(built, travelled, ignore=shutil.ignore_patterns("samples"))
    view, made = bench.prepare(travelled, tmp_path / "out", cores=2)
    assert made == 4 and not (travelled / "samples").exists()  # built in the copy, the folder left as it is
    for path in sorted((built / "samples").glob("*.npz")):
        expected, rebuilt = load_npz(path), load_npz(view / "samples" / path.name)
        assert expected.keys() == rebuilt.keys()
        for key in expected:
            np.testing.assert_array_equal(rebuilt[key], expected[key], err_msg=f"{path.name}: {key}")
    assert bench.prepare(travelled, tmp_path / "out", cores=2)[1] == 0  # a second call builds nothing


def test_the_gpu_machine_s_imports_need_no_triangle():
    """The GPU machine runs the benchmark from the working tree without the project's own install, and
    lacks `triangle` (an evaluation once stopped on it there): the benchmark and the modules its
    evaluation loads import without it."""
    code = ("import sys; sys.modules['triangle'] = None; sys.path[:0] = ['.', 'benchmarks']\n"
            "import importlib.util\n"
            "spec = importlib.util.spec_from_file_location('bench_train_networks', 'benchmarks/train_networks.py')\n"
            "spec.loader.exec_module(importlib.util.module_from_spec(spec))\n"
            "import networks.recognizer_top1, networks.evaluate_detector\n"
            "print('assets.garments' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "False"


def test_the_run_table_shows_the_call_s_synth_weight_not_the_default(bench, capsys):
    """Tables printed again from a results.json (as for RESULTS.md) show the weight the call trained
    with, not the run's default."""
    row = {"step": 10, "target": 10, "steps_this_call": 10, "seconds": 1.0, "steps_per_s": 10.0, "workers": 2,
           "first_loss": 2.0, "last_loss": 1.0, "gpus": [0]}
    result = {"date": "2026-11-26", "machine": "test", "wall_s": 1.0, "shards": {}, "mixes": {},
              "runs": {"localizer_mix": {"synth_weight": 0.5}}, "training": {"localizer_mix": row},
              "heldout_images": 0, "metrics": {}, "detector": {}, "throughput": []}
    assert bench.RUNS["localizer_mix"][1] != 0.5
    bench._print_tables(result)
    assert "| localizer_mix | 0.5 | 0 | 2 | 10 / 10 |" in capsys.readouterr().out


@pytest.fixture(scope="module")
def garment_dataset(tmp_path_factory):
    """One synthesized image per split, and the garment's template."""
    from tests.networks.test_evaluate_detector import write_garment_dataset

    return write_garment_dataset(tmp_path_factory.mktemp("ds"), {"train": 1, "val": 1, "test": 1})


@pytest.fixture(scope="module")
def init_folder(tmp_path_factory):
    """Slim-checkpoint stand-ins of an earlier call's main runs (`--init`): untrained tiny networks."""
    from tests.networks.test_evaluate_detector import untrained_checkpoints

    folder = tmp_path_factory.mktemp("init")
    untrained_checkpoints(folder, MAIN3)
    return folder


def test_a_main_run_not_trained_this_call_is_chained_from_its_init(bench, tmp_path, init_folder):
    init = bench.init_weights(init_folder)
    assert bench.main_checkpoints(tmp_path, {}) is None  # nothing trained, nothing to start from
    assert bench.main_checkpoints(tmp_path, init) == [Path(init[name]) for name in MAIN3]
    trained = tmp_path / "crosspoints_rendered" / "run" / "last.pt"
    trained.parent.mkdir(parents=True)
    shutil.copy(init_folder / "crosspoints_rendered.pt", trained)
    assert bench.main_checkpoints(tmp_path, init)[2] == trained  # this call's run before its start
    assert bench.main_checkpoints(tmp_path, {"localizer_mix": init["localizer_mix"]}) is None


def test_init_takes_a_run_s_own_checkpoint_else_its_task_s_stored_one(bench, tmp_path, init_folder):
    stored = tmp_path / "stored"
    stored.mkdir()
    shutil.copy(init_folder / "localizer_mix.pt", stored / "localizer.pt")  # as networks.weights fetch names it
    shutil.copy(init_folder / "crosspoints_rendered.pt", stored / "crosspoints_rendered.pt")
    init = bench.init_weights(stored)
    localizers = [name for name, run in bench.RUNS.items() if run[0] == "localizer"]
    assert {name: Path(path).name for name, path in init.items() if name in localizers} == \
        {name: "localizer.pt" for name in localizers}
    assert Path(init["crosspoints_rendered"]).name == "crosspoints_rendered.pt"
    assert not any(bench.RUNS[name][0] == "recognizer" for name in init)
    assert bench.init_weights(tmp_path / "missing") == {}
    assert set(bench.init_weights(stored, ["localizer_upright", "crosspoints_rendered", "recognizer"])) == \
        {"localizer_upright", "crosspoints_rendered"}  # this call's runs only


def test_main_runs_are_evaluated_and_exported_as_compact_checkpoints(bench, tmp_path, garment_dataset, init_folder):
    """evaluate_compact: each main run's last.pt as int8 <task>.pt, evaluated on the held-out renders;
    export --export-weights puts them in store/ as networks.weights store takes them."""
    import torch

    from networks.checkpoint import read_checkpoint

    out = tmp_path / "bn"
    for name in MAIN3:
        (out / name / "run").mkdir(parents=True)
        shutil.copy(init_folder / f"{name}.pt", out / name / "run" / "last.pt")
    test = bench.heldout(garment_dataset, out, markers=2)
    compact = bench.evaluate_compact(out, test, "cpu")
    assert list(compact) == ["localizer", "recognizer", "crosspoints"]
    for task, name in zip(compact, MAIN3):
        record = read_checkpoint(out / "compact" / f"{task}.pt")
        assert record["task"] == task and record["int8_scales"] and record["optimizer"] is None
        assert compact[task]["run"] == name and compact[task]["bytes"] == (out / "compact" / f"{task}.pt").stat().st_size
        assert compact[task]["checkpoint"] == str(out / "compact" / f"{task}.pt") and compact[task]["split"] == "heldout"
    assert "all" in compact["localizer"] and "top1" in compact["recognizer"] and "crop_error_px" in compact["crosspoints"]
    (out / "results.json").write_text("{}")
    (out / "localizer_upright" / "run").mkdir(parents=True)  # a comparison run comes back as <run>.pt
    shutil.copy(init_folder / "localizer_mix.pt", out / "localizer_upright" / "run" / "last.pt")
    bench.export(out, tmp_path / "export", weights=True)
    store = tmp_path / "export" / "store"
    assert sorted(p.name for p in store.iterdir()) == \
        ["crosspoints.pt", "localizer.pt", "localizer_upright.pt", "recognizer.pt"]
    assert not (tmp_path / "export" / "weights").exists()
    for name in ("localizer.pt", "localizer_upright.pt"):
        assert torch.load(store / name, weights_only=True)["int8_scales"]
    init = bench.init_weights(store, ["localizer_mix", "localizer_upright"])  # and --init reads them back
    assert {name: Path(path).name for name, path in init.items()} == \
        {"localizer_mix": "localizer.pt", "localizer_upright": "localizer_upright.pt"}


def test_a_checkpoint_several_runs_start_from_is_evaluated_once(bench, tmp_path, garment_dataset, init_folder):
    test = bench.heldout(garment_dataset, tmp_path, markers=2)
    localizer = str(init_folder / "localizer_mix.pt")
    init = {"localizer_mix": localizer, "localizer_upright": localizer,
            "recognizer_partial": str(init_folder / "recognizer_partial.pt")}
    metrics = bench.evaluate_inits(init, test, "cpu")
    assert list(metrics) == list(init)
    assert metrics["localizer_mix"] is metrics["localizer_upright"]  # one evaluation, both runs' baseline
    assert metrics["localizer_mix"]["checkpoint"] == localizer and metrics["localizer_mix"]["split"] == "heldout"
    assert metrics["recognizer_partial"]["task"] == "recognizer"


def test_the_recognizers_top1_is_reported_by_group_and_marker_size(bench, tmp_path, garment_dataset, init_folder,
                                                                   capsys):
    test = bench.heldout(garment_dataset, tmp_path, markers=2)
    ids = bench.evaluate_partial_ids(tmp_path, test, "cpu", bench.init_weights(init_folder))
    assert list(ids) == ["recognizer_partial, its --init"]  # nothing trained here: the start alone
    record = ids["recognizer_partial, its --init"]
    assert set(record) == {"groups", "by_size", "by_visible", "by_residual"}
    counted = sum(r["markers"] for r in record["groups"].values())
    assert counted > 0 and counted == sum(r["markers"] for bins in record["by_size"].values() for r in bins.values())
    whole = record["groups"]["all five points visible"]["markers"]
    shares = {label: r["markers"] for label, r in record["by_visible"].items()}
    assert sum(shares.values()) == whole  # the bins split the whole markers
    bench._print_top1("2 held-out renders", ids)
    printed = capsys.readouterr().out
    assert "| recognizer_partial, its --init | all five points visible | all |" in printed
    assert "| recognizer_partial, its --init | all five points visible | size " in printed
    every = shares.get("every crosspoint visible")
    row = f"| recognizer_partial, its --init | all five points visible | every crosspoint visible | {every} |"
    assert every is None or row in printed
    assert any(f"| {label} | {n} |" in printed for label, n in shares.items())


def test_an_extra_heldout_folder_is_evaluated_on_every_image(bench, tmp_path, garment_dataset, init_folder, capsys):
    # two markers kept of each image: every crop through an untrained ResNet-50 takes seconds on a CPU
    view = bench.heldout(garment_dataset, tmp_path, markers=2, every_split=True, name="heldout_extra")
    assert len(bench.heldout(garment_dataset, tmp_path)
               .joinpath("manifest.jsonl").read_text().splitlines()) == 2  # val and test only
    extra = bench.evaluate_extra(tmp_path, view, "cpu", bench.init_weights(init_folder), smoke=True)
    assert extra["images"] == 3 and set(extra["metrics"]) == {"localizer", "recognizer", "crosspoints"}
    chain = extra["detector"]["localizer scale 1"]  # the images are 128 px: no second fixed scale
    labels = list(extra["detector"])
    assert labels[0] == "localizer scale 1" and chain["images"] == 3 and chain["split"] == "heldout"
    automatic = extra["detector"][labels[1]]  # and the scale chosen per image
    assert len(labels) == 2 and labels[1].startswith("localizer scale auto (") and automatic["images"] == 3
    assert automatic["localizer_scale"]["config"] is None and automatic["localizer_scale"]["max"] <= 1.0
    assert sum(r["markers"] for r in extra["recognizer_top1"]["groups"].values()) > 0
    result = {"date": "2026-11-26", "machine": "test", "wall_s": 1.0, "shards": {}, "mixes": {}, "runs": {},
              "training": {}, "heldout_images": 2, "metrics": {}, "detector": {}, "throughput": [], "extra": extra}
    bench._print_tables(result)
    printed = capsys.readouterr().out
    assert "| Detector, three runs chained (3 renders of --extra-heldout) |" in printed
    assert "| localizer scale 1 |" in printed
    assert "| recognizer (step 0).top1 |" in printed


def test_runs_from_init_take_lr_or_init_lr(bench):
    init = {"localizer_upright": "/weights/localizer.pt", "recognizer_partial": "/weights/recognizer_partial.pt"}
    assert bench.run_config("localizer_upright", 1, 2, {}, init).lr == bench.LR
    assert bench.run_config("localizer_upright", 1, 2, {}, init, init_lr=5e-5).lr == 5e-5
    assert bench.run_config("localizer_mix", 1, 2, {}, init, init_lr=5e-5).lr == bench.LR  # from scratch
    assert bench.run_config("recognizer_partial", 1, 2, {}, init).lr == bench.LR
    assert bench.run_config("recognizer_partial", 1, 2, {}, init, init_lr=1e-5).lr == 1e-5
    assert bench.run_config("crosspoints_jitter", 1, 2, {}, init, init_lr=1e-5).lr == bench.LR  # from scratch


def test_runs_and_their_init_are_measured_on_held_out_synthesized_samples(bench, tmp_path, garment_dataset,
                                                                          init_folder, capsys):
    folders = bench.synth_heldout(tmp_path, garment_dataset, 1, True, ["localizer_mix", "recognizer_partial",
                                                                       "localizer_synth"])
    assert set(folders) == {"localizer", "recognizer_partial"}  # one folder for both localizer runs
    meta = json.loads((folders["localizer"] / "shards.json").read_text())
    assert meta["synth"]["seed"] == bench.SYNTH_HELDOUT[1] != bench.SynthConfig().seed  # not the training samples
    trained = tmp_path / "localizer_synth" / "run" / "last.pt"
    trained.parent.mkdir(parents=True)
    shutil.copy(init_folder / "localizer_mix.pt", trained)
    init = {k: v for k, v in bench.init_weights(init_folder).items() if k != "crosspoints_rendered"}
    measured = bench.evaluate_synthesized(tmp_path, folders, "cpu", init)
    assert set(measured) == {"localizer_synth", "localizer_mix, its --init", "recognizer_partial, its --init"}
    assert all(m["split"] == "shards" and m["samples"] > 0 for m in measured.values())
    assert measured["localizer_synth"]["all"] == measured["localizer_mix, its --init"]["all"]  # the same weights
    bench._print_metrics(measured)
    assert "| recognizer_partial, its --init (step 0).top1 |" in capsys.readouterr().out


def test_the_upright_localizer_run_draws_its_own_shards_with_markers_near_upright(bench, tmp_path, garment_dataset):
    assert bench.shard_config("localizer_upright").upright_probability == 1.0
    assert bench.shard_config("localizer").upright_probability == bench.SynthConfig().upright_probability < 1.0
    assert bench.shard_config("localizer_upright", 5).seed == 5
    assert bench.shard_config("crosspoints_jitter").crop_jitter_px == bench.CROP_JITTER_PX
    folders = bench.synth_heldout(tmp_path, garment_dataset, 1, True, ["localizer_synth", "localizer_upright"])
    assert set(folders) == {"localizer", "localizer_upright"}
    meta = json.loads((folders["localizer_upright"] / "shards.json").read_text())
    assert meta["synth"]["upright_probability"] == 1.0 and meta["synth"]["seed"] == bench.SYNTH_HELDOUT[1]
    written = bench.make_shards(tmp_path, garment_dataset, 1, 60.0, True, ["localizer_upright"])
    assert set(written) == {"localizer_upright"}
    assert json.loads((tmp_path / "shards" / "localizer_upright" / "shards.json").read_text()
                      )["synth"]["upright_probability"] == 1.0


def test_throughput_times_each_size_with_the_defaults_and_each_variant_on_the_same_images(bench, tmp_path,
                                                                                        init_folder, capsys):
    rows = bench.throughput(tmp_path, "cpu", (256,), 1, smoke=True, init=bench.init_weights(init_folder))
    variants = ["defaults", *bench.THROUGHPUT_VARIANTS]
    assert [(r["size"], r["variant"]) for r in rows] == [(256, v) for v in variants]
    assert len({(r["shown_per_image"], r["shown_first_image"]) for r in rows}) == 1  # the same images
    assert len({r["found_first_image"] for r in rows}) == 1  # smoothing moves crosspoints, never markers
    assert all(r["images_per_s"] > 0 and r["stage_seconds"]["crosspoints"] >= 0 for r in rows)
    bench._print_tables({"date": "2026-11-27", "machine": "test", "wall_s": 1.0, "shards": {}, "mixes": {},
                         "runs": {}, "training": {}, "heldout_images": 0, "metrics": {}, "detector": {},
                         "throughput": rows})
    printed = capsys.readouterr().out
    assert "| cpu | 256 x 256 | no crosspoint smoothing | 1 |" in printed


def test_the_small_marker_recognizer_run_differs_from_the_main_one_only_in_its_markers(bench):
    small, main = bench.shard_config("recognizer_small"), bench.shard_config(bench.MAIN["recognizer"])
    assert small.marker_px == (10.0, 32.0) and main.marker_px[0] == 16.0
    assert small == main.__class__(**{**main.__dict__, "marker_px": (10.0, 32.0)})
    assert bench.RUNS["recognizer_small"][:4] == bench.RUNS[bench.MAIN["recognizer"]][:4]
    assert bench.run_config("recognizer_small", 1, 2, {}).recognizer_partial


def _f1(f1: float) -> dict:
    return {"full": {"f1": f1}}


def test_the_best_f1_is_chosen_and_a_tie_goes_to_the_higher_threshold(bench):
    assert bench.choose_threshold({0.3: _f1(0.990), 0.4: _f1(0.996), 0.5: _f1(0.993)}) == 0.4
    assert bench.choose_threshold({0.3: _f1(0.99), 0.4: _f1(0.99), 0.5: _f1(0.98)}) == 0.4
    assert bench.choose_threshold({0.2: _f1(0.9), 0.5: _f1(0.9)}) == 0.5  # the reference, at equal F1
    with pytest.raises(ValueError, match="no thresholds"):
        bench.choose_threshold({})


def test_thresholds_always_include_the_reference_and_bad_ones_are_refused(bench):
    assert bench.thresholds_arg("0.4,0.2,0.4") == [0.2, 0.4, 0.5]
    for text, problem in (("0.3,x", "not a comma-separated list"), ("0,0.3", r"\[0.0\] are not in"),
                          ("1.5", r"\[1.5\] are not in")):
        with pytest.raises(argparse.ArgumentTypeError, match=problem):
            bench.thresholds_arg(text)


def test_choosing_the_threshold_on_the_split_it_is_tested_on_is_refused(bench, tmp_path):
    with pytest.raises(ValueError, match="another split than the one it is tested on"):
        bench.sweep(tmp_path / "l.pt", tmp_path, [0.3], "test", "test")


def test_the_presence_threshold_is_chosen_on_val_and_checked_on_test(bench, tmp_path, capsys):
    """The benchmark's stage on a real (tiny, untrained) localizer: every threshold on the val split,
    the chosen one and the reference on the test split; no stage without a val split."""
    from tests.networks.test_evaluate_detector import untrained_checkpoints, write_garment_dataset

    data = write_garment_dataset(tmp_path / "ds", {"train": 1, "val": 1, "test": 1})
    untrained_checkpoints(tmp_path / "init", MAIN3)
    init = bench.init_weights(tmp_path / "init")
    result = bench.evaluate_threshold(tmp_path / "out", data, "cpu", init)
    assert result["checkpoint"] == init["localizer_mix"]
    assert list(result["choose"]) == [0.2, 0.3, 0.35, 0.4, 0.45, 0.5]
    assert all(m["split"] == "val" and m["task"] == "localizer" for m in result["choose"].values())
    assert set(result["test"]) == {result["chosen"], 0.5}
    assert all(m["split"] == "test" for m in result["test"].values())
    found = [m["all"]["true_positive"] + m["all"]["false_positive"] for m in result["choose"].values()]
    assert found == sorted(found, reverse=True)  # a lower threshold keeps at least as many predictions
    bench.print_sweep(json.loads(json.dumps(result)), "# sweep")  # as results.json holds it: string keys
    printed = capsys.readouterr().out.splitlines()
    assert len([line for line in printed if line.startswith("| 0.")]) == 6 + len(result["test"])
    assert sum("(chosen)" in line for line in printed) == 2 and any(line.startswith("| 0.5") for line in printed)
    manifest = data / "manifest.jsonl"
    manifest.write_text("".join(line + "\n" for line in manifest.read_text().splitlines()
                                if json.loads(line)["split"] != "val"))
    assert bench.evaluate_threshold(tmp_path / "out", data, "cpu", init) == {}
