"""`python -m reconstruction` end to end on the session's tiny capture, in the ground-truth mode: every
stage's files, the evaluation, resume, and refusal of a folder made with other settings."""

import json
import shutil

import numpy as np
import pytest

from reconstruction.__main__ import main
from reconstruction.groundtruth import GroundTruthCapture
from reconstruction.points import load_sequence
from reconstruction.refinement import RefinedSequence

pytestmark = pytest.mark.slow  # Newton's first kernel compile and the shared capture


def test_the_cli_reconstructs_a_capture_and_resumes(capture_folder, tmp_path, capsys):
    out = tmp_path / "rec"
    argv = ["run", "--views", str(capture_folder), "--template", str(capture_folder / "template.npz"),
            "--out", str(out), "--detections", "groundtruth", "--levels", "12", "--evaluate", "--no-progress"]
    assert main(argv) == 0
    cameras = [c["name"] for c in json.loads((capture_folder / "cameras.json").read_text())["cameras"]]
    for camera in cameras:
        assert sorted(p.name for p in (out / "detections" / camera).iterdir()) == ["f000003.npz", "f000004.npz"]
    run = json.loads((out / "run.json").read_text())  # refine started from the capture's dressed garment
    assert run["initial_shape"] == str((capture_folder / "sim" / "dressed.npz").resolve())
    points = load_sequence(out / "points")
    assert [p.frame for p in points] == [3, 4]
    assert all(p.source.startswith("groundtruth(") for p in points)  # named as such in every output
    sequence = RefinedSequence.load(out / "sequence.npz")
    assert sequence.source.startswith("groundtruth(") and sequence.positions.shape[0] == 2
    assert np.isfinite(sequence.positions).all() and sequence.captured.any()
    summary = json.loads((out / "evaluation.json").read_text())["summary"]
    # noise-free: every point seen twice, but for the small patches of these 96 x 64 views that no
    # other marker's crosspoints confirm (the neighbour check drops them)
    assert 0.95 < summary["captured_fraction"] <= 1.0
    # three 96 x 64 views of one side see part of the garment: the rest of its crosspoints is filled
    assert 0.0 < summary["garment_coverage"] < summary["captured_fraction"]
    crosspoints = GroundTruthCapture(capture_folder).crosspoint_map
    for row, frame in zip(json.loads((out / "evaluation.json").read_text())["frames"], points):
        captured = np.unique(crosspoints.flat(frame.key))
        assert (crosspoints.face[captured] >= 0).all()  # points lie on the fabric
        assert row["garment_coverage"] == len(captured) / (crosspoints.face >= 0).sum()
    assert summary["error_mm_median"] < 1e-3
    assert summary["intersections_after_max"] == 0
    assert (out / "export" / "sequence.npz").is_file() and (out / "export" / "review.blend").is_file()

    stamps = {p: p.stat().st_mtime_ns for p in (out / "points").iterdir()}
    assert main(argv) == 0  # resumes: nothing is redone
    assert {p: p.stat().st_mtime_ns for p in (out / "points").iterdir()} == stamps

    # triangulating again with other settings would mix points made two ways: refused by name
    capsys.readouterr()
    assert main(["triangulate", "--out", str(out), "--no-neighbour-check", "--no-progress"]) != 0
    assert "points/triangulation.json" in (err := capsys.readouterr().err) and "(neighbours: {" in err
    assert {p: p.stat().st_mtime_ns for p in (out / "points").iterdir()} == stamps

    # without the neighbour check, in a folder of its own: the same detections give every point, the
    # dropped patches too
    unchecked = tmp_path / "unchecked"
    shutil.copytree(out / "detections", unchecked / "detections")
    shutil.copy2(out / "run.json", unchecked / "run.json")
    assert main(["triangulate", "--out", str(unchecked), "--no-neighbour-check", "--no-progress"]) == 0
    for checked, kept in zip(points, load_sequence(unchecked / "points")):
        assert set(map(tuple, checked.key)) <= set(map(tuple, kept.key))
    assert sum(len(p.key) for p in load_sequence(unchecked / "points")) > sum(len(p.key) for p in points)
    assert json.loads((unchecked / "points" / "triangulation.json").read_text())["neighbours"] is None
    # points without a record (an older version's) are all made again
    (unchecked / "points" / "triangulation.json").unlink()
    made = {p: p.stat().st_mtime_ns for p in (unchecked / "points").glob("f*.npz")}
    assert main(["triangulate", "--out", str(unchecked), "--no-neighbour-check", "--no-progress"]) == 0
    assert all(p.stat().st_mtime_ns != made[p] for p in made)

    capsys.readouterr()
    assert main(argv[:-2] + ["--noise", "0.5", "--no-progress"]) != 0
    assert "run.json: this folder holds a run made with other settings or inputs (noise_px: 0.0 -> 0.5)" \
        in capsys.readouterr().err


def test_a_missing_initial_shape_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "rec"
    argv = ["detect", "--views", str(tmp_path), "--template", "shirt", "--out", str(out),
            "--detections", "groundtruth", "--initial-shape", str(tmp_path / "nowhere.npz"), "--no-progress"]
    assert main(argv) != 0
    assert "nowhere.npz: no such file" in capsys.readouterr().err
    assert not out.exists()
