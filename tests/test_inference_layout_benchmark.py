"""`benchmarks/inference_layout.py`: each network timed in both memory layouts on the same inputs."""


def test_each_network_is_timed_in_both_layouts(load_benchmark, capsys):
    bench = load_benchmark("inference_layout")
    assert bench.main(["--image", "64", "--crops", "1", "--repeats", "1", "--rounds", "1"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "---" not in line]
    assert [row.split(" | ")[0] for row in rows[1:]] == ["| localizer", "| recognizer", "| crosspoints"]
    for row in rows[1:]:
        nchw, nhwc, ratio = (float(cell) for cell in row.strip(" |").split(" | ")[2:])
        assert nchw > 0 and nhwc > 0 and abs(ratio - nhwc / nchw) <= 0.006 + 0.002 * ratio  # 4 digits, 2 decimals
    assert "1x3x64x64" in rows[1] and "1x3x112x112 + 1x3x112x112" in rows[3]
