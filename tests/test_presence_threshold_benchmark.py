"""`benchmarks/presence_threshold.py`: the threshold is chosen on one split by F1 and checked on another."""

import argparse

import pytest


@pytest.fixture(scope="module")
def bench(load_benchmark):
    return load_benchmark("presence_threshold")


def _metrics(f1: float) -> dict:
    return {"full": {"f1": f1}}


def test_the_best_f1_is_chosen_and_a_tie_goes_to_the_higher_threshold(bench):
    assert bench.choose({0.3: _metrics(0.990), 0.4: _metrics(0.996), 0.5: _metrics(0.993)}) == 0.4
    assert bench.choose({0.3: _metrics(0.99), 0.4: _metrics(0.99), 0.5: _metrics(0.98)}) == 0.4
    assert bench.choose({0.2: _metrics(0.9), 0.5: _metrics(0.9)}) == 0.5  # the reference, at equal F1
    with pytest.raises(ValueError, match="no thresholds"):
        bench.choose({})


def test_thresholds_always_include_the_reference_and_bad_ones_are_refused(bench):
    assert bench.thresholds_arg("0.4,0.2,0.4") == [0.2, 0.4, 0.5]
    for text, problem in (("0.3,x", "not a comma-separated list"), ("0,0.3", r"\[0.0\] are not in"),
                          ("1.5", r"\[1.5\] are not in")):
        with pytest.raises(argparse.ArgumentTypeError, match=problem):
            bench.thresholds_arg(text)


def test_choosing_on_the_test_split_is_refused(bench, tmp_path):
    with pytest.raises(SystemExit, match="another split than the one it is tested on"):
        bench.main(["--checkpoint", str(tmp_path / "l.pt"), "--data", str(tmp_path), "--choose-split", "test"])


def test_the_networks_benchmark_chooses_on_val_and_checks_on_test(load_benchmark, bench, tmp_path, capsys):
    """The benchmark's stage on a real (tiny, untrained) localizer: every threshold on the val split,
    the chosen one and the reference on the test split; no stage without a val split."""
    import json

    from tests.networks.test_evaluate_detector import untrained_checkpoints, write_garment_dataset

    networks = load_benchmark("networks")
    data = write_garment_dataset(tmp_path / "ds", {"train": 1, "val": 1, "test": 1})
    untrained_checkpoints(tmp_path / "init", ["localizer_mix", "recognizer_partial", "crosspoints_rendered"])
    init = networks.init_weights(tmp_path / "init")
    result = networks.evaluate_threshold(tmp_path / "out", data, "cpu", init)
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
    assert networks.evaluate_threshold(tmp_path / "out", data, "cpu", init) == {}
