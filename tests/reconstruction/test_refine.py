"""The Newton post-processing on a 12 mm template: one refine step reaches the captured points and
removes a planted intersection; a short sequence propagates, smooths, upsamples and resumes."""

import numpy as np
import pytest

from reconstruction.anchors import LevelAnchoring
from reconstruction.intersections import count_intersections
from reconstruction.refinement import RefineConfig, RefinedSequence, load_initial_shape, refine_sequence
from tests.reconstruction.cylinder import (
    HEIGHT, RADIUS, WIDTH, bent, captured_points, cylinder_template, every_key, key_pattern_xy, sewn_pattern_xy,
    wrapped,
)

CENTRE = np.array([WIDTH / 2, HEIGHT / 2])  # of the front panel, where the cameras see nothing


@pytest.fixture(scope="module")
def cylinder():
    template = cylinder_template()
    anchoring = LevelAnchoring(template, 12)
    key = every_key(anchoring)
    panel, xy = key_pattern_xy(template, anchoring, key)
    seen = key[~((panel == 0) & (np.linalg.norm(xy - CENTRE, axis=1) < 0.065))]
    return template, anchoring, seen


def test_one_refine_step_reaches_the_capture_and_removes_a_planted_intersection(cylinder):
    template, anchoring, seen = cylinder
    faces = template.level(12).sewn_faces
    rest = wrapped(template, 12)
    truth = bent(rest, 0.15, (0.05, 0.0, 0.02))
    capture = captured_points(anchoring, truth, seen)
    # the start: the template at rest with a patch of the unseen front pushed through the back
    start = rest.copy()
    panel, xy = sewn_pattern_xy(template, 12)
    distance = np.linalg.norm(xy - CENTRE, axis=1)
    patch = (panel == 0) & (distance < 0.045)
    start[patch, 1] -= (2 * RADIUS + 0.02) * np.cos(np.pi * distance[patch] / 0.09) ** 2
    assert count_intersections(rest, faces) == 0 and count_intersections(start, faces) > 0

    result = refine_sequence(template, [capture], RefineConfig(levels_mm=(12,)), progress=False,
                             initial_shape=start, initial_level_mm=12)
    report = result.diagnostics[0]
    captured = result.captured[0]
    assert captured.sum() > 0.8 * len(captured) and not captured[patch].any()
    start_residual = np.linalg.norm(start[captured] - truth[captured], axis=1)
    assert np.sqrt(np.mean(start_residual**2)) > 0.02  # 2 cm away before...
    assert report["anchor_rms_mm"] < 0.01 and report["anchor_max_mm"] < 0.1  # ...on target after
    assert report["intersections_before"] > 0 and report["intersections_start"] > 0
    assert report["intersections_after"] == 0
    assert count_intersections(result.positions[0].astype(np.float64), faces) == 0
    error = np.linalg.norm(result.positions[0] - truth, axis=1)
    assert np.median(error[captured]) < 1e-4
    assert error[~captured].max() < 0.02  # the unseen patch is filled near the truth, on the right side


def test_a_short_sequence_propagates_smooths_upsamples_and_resumes(cylinder, tmp_path):
    template, anchoring, seen = cylinder
    rest = wrapped(template, 12)
    rng = np.random.default_rng(0)
    truths = [bent(rest, amount, (0.01 * t, 0.0, 0.0)) for t, amount in enumerate((0.08, 0.10, 0.12))]
    # frame 1 sees the most: the start frame; frames 0 and 2 miss an extra strip of the back
    panel, xy = key_pattern_xy(template, anchoring, seen)
    strip = (panel == 1) & (xy[:, 1] > 0.2)
    captures = [captured_points(anchoring, truths[t], seen[~strip] if t != 1 else seen, frame=10 + t, noise=2e-4,
                                rng=rng) for t in range(3)]
    config = RefineConfig(levels_mm=(12, 4), steps=4)
    out = tmp_path / "refine"
    result = refine_sequence(template, captures, config, progress=False, out=out,
                             initial_shape=rest, initial_level_mm=12)
    level = template.level(4)
    assert result.level_mm == 4 and result.start_frame == 1 and result.frames.tolist() == [10, 11, 12]
    assert result.positions.shape == (3, level.num_sewn_vertices, 3) and result.captured.shape == (3, level.num_sewn_vertices)
    assert result.source == "test" and result.config["levels_mm"] == [12, 4]
    fine_truths = [bent(wrapped(template, 4), amount, (0.01 * t, 0.0, 0.0)) for t, amount in enumerate((0.08, 0.10, 0.12))]
    for t in range(3):
        report = result.diagnostics[t]
        assert report["intersections_after"] == 0
        assert set(report["pass1"]["levels"]) == {"12", "4"}  # pass 1 solved both levels, pass 2 the finest
        error = np.linalg.norm(result.positions[t] - fine_truths[t], axis=1)
        captured = result.captured[t]
        assert np.median(error[captured]) < 5e-4  # noise 0.2 mm per coordinate, averaged by the fit
        assert np.percentile(error[~captured], 95) < 0.02
    assert result.captured[1].sum() > result.captured[0].sum()
    assert sorted(p.name for p in (out / "final").iterdir()) == ["f000010.npz", "f000011.npz", "f000012.npz"]

    path = tmp_path / "refined.npz"
    result.save(path)
    loaded = RefinedSequence.load(path)
    assert np.array_equal(loaded.positions, result.positions) and loaded.diagnostics == result.diagnostics

    solved = {p: p.stat().st_mtime_ns for p in out.rglob("*.npz")}
    again = refine_sequence(template, captures, config, progress=False, out=out, initial_shape=rest,
                            initial_level_mm=12)  # every frame on file: nothing is solved again
    assert np.array_equal(again.positions, result.positions) and again.diagnostics == result.diagnostics
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*.npz")} == solved
    record = (out / "refine_run.json").read_text()
    with pytest.raises(ValueError, match=r"refine_run.json: .*\(steps: 4 -> 3\)"):
        refine_sequence(template, captures, RefineConfig(levels_mm=(12, 4), steps=3), progress=False, out=out,
                        initial_shape=rest, initial_level_mm=12)
    fewer = [c.select(np.arange(len(c) - 1)) for c in captures]  # other points, the same settings
    with pytest.raises(ValueError, match=r'\(captures: "[0-9a-f]{40}" -> "[0-9a-f]{40}"\)'):
        refine_sequence(template, fewer, config, progress=False, out=out, initial_shape=rest, initial_level_mm=12,
                        start_frame=1)
    assert (out / "refine_run.json").read_text() == record


def test_bad_input_is_named(cylinder, tmp_path):
    template, anchoring, seen = cylinder
    capture = captured_points(anchoring, wrapped(template, 12), seen)
    with pytest.raises(ValueError, match="captures"):
        refine_sequence(template, [], progress=False)
    with pytest.raises(ValueError, match="start_frame"):
        refine_sequence(template, [capture], RefineConfig(levels_mm=(12,)), start_frame=3, progress=False)
    with pytest.raises(ValueError, match="levels_mm"):
        RefineConfig(levels_mm=(12, 12))
    with pytest.raises(ValueError, match="at least 3"):
        refine_sequence(template, [capture.select(np.arange(2))], RefineConfig(levels_mm=(12,)), progress=False)
    config = RefineConfig(levels_mm=(12, 4), anchor_weight=2e6)
    config.save(tmp_path / "refine.json")
    assert RefineConfig.load(tmp_path / "refine.json") == config
    (tmp_path / "bad.json").write_text('{"anchor_wieght": 1}')
    with pytest.raises(ValueError, match="anchor_wieght"):
        RefineConfig.load(tmp_path / "bad.json")
    np.savez(tmp_path / "dressed.npz", positions=np.zeros((4, 3)), meta=np.array('{"garment": "x"}'))
    with pytest.raises(ValueError, match="level_mm"):
        load_initial_shape(tmp_path / "dressed.npz")


def test_a_cuda_device_without_one_is_refused_by_name(cylinder):
    import warp as wp

    if wp.is_cuda_available():
        pytest.skip("this machine has a CUDA device: the refusal cannot happen here")
    template, anchoring, seen = cylinder
    capture = captured_points(anchoring, wrapped(template, 12), seen)
    with pytest.raises(ValueError, match="refine device 'cuda:0': warp sees no CUDA device"):
        refine_sequence(template, [capture], RefineConfig(levels_mm=(12,)), progress=False, device="cuda:0")
