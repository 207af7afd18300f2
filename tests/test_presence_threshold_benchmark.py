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


def test_choosing_on_the_test_split_is_refused(bench, tmp_path, capsys):
    with pytest.raises(SystemExit):
        bench.main(["--checkpoint", str(tmp_path / "l.pt"), "--data", str(tmp_path), "--choose-split", "test"])
    assert "must differ" in capsys.readouterr().err
