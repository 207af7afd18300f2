"""The dataset build (`factory.build`) and the capture (`factory.dataset`) on the session's short shirt
walk: real Blender renders (small), real ground truth; the simulation is the shared fixture's, copied
into each dataset folder."""

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from assets.cameras import Camera
from factory.build import build
from factory.plan import DatasetConfig, RenderSettings, simulation_config, split_of_frames
from factory.scenes import corner_uv, render_job_spec, write_scene
from assets.garments.markers import MarkerSurface
from factory.groundtruth import image_ground_truth

PROJECT = Path(__file__).resolve().parents[2]
TINY = RenderSettings(resolution=(64, 64), engine="WORKBENCH", samples=1, denoise=False)


def _seeded(out: Path, shirt_run) -> Path:
    """A dataset folder holding the fixture's simulation, so the build reuses it."""
    _, sim, _ = shirt_run
    (out / "sim").mkdir(parents=True)
    shutil.copytree(sim, out / "sim" / "walk")
    return out


def _config(**overrides) -> DatasetConfig:
    return DatasetConfig(garment="shirt", motions=("walk",), frame_list=(2, 4, 5), variations=2, render=TINY,
                         **overrides)


def _record(out: Path, config: DatasetConfig) -> None:
    """`factory.build.prepare`'s settings check and record alone (no template written)."""
    from assets.fileio import record_stage
    from factory.build import config_record

    record_stage(out / "config.json", config_record(config))


def test_splits_keep_the_reference_ratio_and_never_share_a_frame():
    units = [("walk", f) for f in range(250)] + [("run", f) for f in range(250)]
    split = split_of_frames(units, seed=3)
    counts = {s: sum(v == s for v in split.values()) for s in ("train", "val", "test")}
    assert counts == {"train": 440, "val": 40, "test": 20}  # 22 : 2 : 1
    assert split == split_of_frames(units, seed=3)
    assert split != split_of_frames(units, seed=4)


@pytest.fixture(scope="module")
def built(tmp_path_factory, shirt_run) -> Path:
    """A dataset of `_config()` built once for the module's tests that only read it (or a copy)."""
    out = _seeded(tmp_path_factory.mktemp("built") / "ds", shirt_run)
    build(_config(), out, progress=False)
    return out


def test_build_writes_every_image_with_ground_truth_and_keeps_frames_within_a_split(built):
    out = built
    manifest = out / "manifest.jsonl"
    entries = [json.loads(line) for line in manifest.read_text().splitlines()]
    assert len(entries) == 3 * 2
    by_frame = {}
    for e in entries:
        by_frame.setdefault((e["motion"], e["frame"]), set()).add(e["split"])
        for key in ("image", "depth", "camera", "gt", "samples"):
            assert (out / e[key]).is_file(), e[key]
    assert all(len(s) == 1 for s in by_frame.values())  # the variations of a frame share its split
    # each record names its simulation, as merge tells simulations apart by
    assert {e["simulation"] for e in entries} == {simulation_config("shirt", "walk").key()}
    assert simulation_config("shirt", "walk", seed=1).key() != simulation_config("shirt", "walk").key()
    assert {s for v in by_frame.values() for s in v} == {"train", "val", "test"}
    samples = np.load(out / entries[0]["samples"])
    assert samples["cells"].shape == (8, 8, 11)
    assert sum(e["markers_visible"] for e in entries) > 0


def test_a_killed_build_resumes_to_byte_identical_output(tmp_path, shirt_run, built):
    whole = built
    broken = _seeded(tmp_path / "broken", shirt_run)
    command = [sys.executable, "-m", "factory.dataset", "build", "--garment", "shirt", "--motions", "walk",
               "--frame-list", "2,4,5", "--variations", "2", "--resolution", "64", "--engine", "WORKBENCH",
               "--samples", "1", "--no-denoise", "--out", str(broken)]
    process = subprocess.Popen(command, cwd=PROJECT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not list((broken / "images").glob("*.png")) and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (broken / "manifest.jsonl").exists()  # it was stopped before the end
    build(_config(), broken, progress=False)
    def outputs(root: Path) -> list[Path]:
        """The dataset, not the work files (sim, jobs, timing) nor a killed writer's hidden temporary."""
        return sorted(p.relative_to(root) for p in root.rglob("*") if p.is_file() and not p.name.startswith(".")
                      and not {"sim", "jobs"} & set(p.relative_to(root).parts) and p.name != "timing.json")

    files = outputs(whole)
    assert files == outputs(broken)
    for f in files:
        assert (whole / f).read_bytes() == (broken / f).read_bytes(), f


def test_a_build_with_other_settings_is_refused(tmp_path, built):
    out = tmp_path / "ds"
    shutil.copytree(built, out)
    with pytest.raises(ValueError, match=r"config.json: .*other settings or inputs \(seed: 0 -> 1\)"):
        build(_config(seed=1), out, progress=False)


def test_projected_crosspoints_agree_with_blenders_position_pass(tmp_path, shirt_run):
    """Ground truth against the renderer: where Cycles' position pass says each visible crosspoint
    is seen, within 0.1 px on average of where the ground truth projects it."""
    from factory.scenes import read_depth, read_exr, render_template
    from factory.render import render_job

    _, sim, sequence_path = shirt_run
    data = np.load(sequence_path)
    template = render_template("shirt", 100.0, tmp_path)
    positions = data["positions"][5].astype(np.float64)
    centre = 0.5 * (positions.min(0) + positions.max(0))
    camera = Camera.look_at(centre + [0.0, -1.6, 0.1], centre, focal_mm=50.0, width=160, height=160)
    write_scene(tmp_path / "scene.npz", positions[None], data["faces"], corner_uv(template, 12), np.array([5]),
                None, None)
    image = {"name": "pos", "frame": 5, "camera": camera.to_dict(), "transform": np.eye(4).tolist(),
             "environment": {"type": "sky", "sun_elevation_deg": 40.0, "sun_rotation_deg": 30.0, "strength": 0.5},
             "cloth": {"roughness": 0.8, "sheen": 0.5}, "skin": {"rgb": [0.8, 0.6, 0.5]}, "seed": 1}
    settings = RenderSettings(resolution=(160, 160), samples=4, denoise=False)
    job = render_job_spec(settings, Path("scene.npz"), Path("texture.png"), [image], position=True)
    (tmp_path / "job.json").write_text(json.dumps(job))
    render_job(tmp_path / "job.json", tmp_path / "out", progress=False)
    surface = MarkerSurface.build(template, 12)
    gt = image_ground_truth(surface, positions, camera, read_depth(tmp_path / "out" / "pos_depth.exr"))
    channels = read_exr(tmp_path / "out" / "pos_position.exr")
    field = np.stack([channels[a] for a in "XYZ"], axis=-1)  # (H, W, 3) world position per pixel
    errors = []
    pixel_centres = np.stack(np.meshgrid(np.arange(3) - 1.0, np.arange(3) - 1.0), -1).reshape(-1, 2)
    for m in np.flatnonzero(gt.status > 0):
        points = gt.crosspoints_px[m][gt.crosspoint_visible[m]][::7]
        world = surface.points(positions)[1][m][gt.crosspoint_visible[m]][::7]
        for p, x in zip(points, world):
            c = np.floor(p).astype(int)
            if not (2 <= c[0] < 158 and 2 <= c[1] < 158):
                continue
            patch = field[c[1] - 1:c[1] + 2, c[0] - 1:c[0] + 2].reshape(-1, 3)
            if not np.isfinite(patch).all() or np.ptp(patch, axis=0).max() > 0.02:
                continue  # a silhouette or a fold in the 3 x 3 pixels: the pass is not one plane there
            # affine fit pixel -> position over the 3 x 3 pixel centres, then the pixel of x
            a = np.c_[pixel_centres, np.ones(9)]
            coef, *_ = np.linalg.lstsq(a, patch, rcond=None)
            offset, *_ = np.linalg.lstsq(coef[:2].T, x - coef[2], rcond=None)
            errors.append(np.linalg.norm(c + 0.5 + offset - p))
    assert len(errors) > 50
    assert np.mean(errors) < 0.1, np.mean(errors)


def test_a_capture_frames_the_garment_in_every_camera_and_its_files_agree(capture_folder, shirt_run):
    """The synthetic capture reconstruction is measured on (the session's, which the reconstruction
    tests share): every camera of the ring sees the whole garment, large; the saved ground truth is
    what cameras.json and garment.npz give."""
    from assets.cameras import load_cameras
    from assets.garments import Template
    from assets.pattern.observation import ImageGroundTruth
    from factory.capture import capture
    from factory.scenes import read_depth

    _, sim, _ = shirt_run
    out = capture_folder
    cameras = load_cameras(out / "cameras.json")
    garment = np.load(out / "garment.npz")
    assert [c.name for c in cameras] == ["cam00", "cam01", "cam02"]
    assert garment["frames"].tolist() == [3, 4]
    surface = MarkerSurface.build(Template.load(out / "template.npz"), int(garment["level_mm"]))
    for camera in cameras:
        assert (camera.width, camera.height) == (96, 64)
        pixels, z = camera.project(garment["positions"].reshape(-1, 3))
        assert (z > 0).all() and (pixels >= 0).all() and (pixels < [96, 64]).all()  # all of it in view
        assert (np.ptp(pixels, axis=0) / [96, 64]).max() > 0.6  # and large
        for t, frame in enumerate(garment["frames"]):
            saved = ImageGroundTruth.load(out / camera.name / f"f{frame:06d}_gt.npz")
            depth = read_depth(out / camera.name / f"f{frame:06d}_depth.exr")
            again = image_ground_truth(surface, garment["positions"][t], camera, depth)
            kept = again.status > 0
            assert saved.num_markers == kept.sum() > 0
            np.testing.assert_array_equal(saved.marker_id, again.marker_id[kept])
            np.testing.assert_allclose(saved.points_px, again.points_px[kept], atol=1e-4)
    assert (out / "contact_sheet.png").is_file()
    assert json.loads((out / "capture.json").read_text())["betas"] is None
    with pytest.raises(ValueError, match=r"other settings or inputs \(betas: \(none\) -> \[0.5, 0.5, 0.65\]; simulation: "):
        capture("shirt", "walk", out, frames=2, first_frame=3, cameras=3, resolution=(96, 64), render=TINY,
                progress=False, simulation=sim, betas=(0.5, 0.5, 0.65))


def _finished_simulation(folder: Path, config) -> Path:
    """A simulation folder as `factory.simulate` records one (only what reuse reads: its meta)."""
    from dataclasses import asdict

    from assets.fileio import save_npz

    meta = {"key": config.key(), "config": json.loads(json.dumps(asdict(config), default=str))}
    save_npz(folder / "sequence.npz", {"positions": np.zeros((1, 3, 3), np.float32), "meta": np.array(json.dumps(meta))})
    return folder


def test_reusing_a_simulation_made_with_other_options_is_refused_naming_them(tmp_path, capsys):
    from factory.dataset import main
    from factory.plan import reuse_simulation, simulation_config

    made = _finished_simulation(tmp_path, simulation_config("skirt", "walk", frames=3))
    reuse_simulation(made, tmp_path / "same" / "sim", simulation_config("skirt", "walk", frames=200))
    assert (tmp_path / "same" / "sim" / "sequence.npz").is_file()  # longer: the simulation continues it

    argv = ["capture", "--garment", "skirt", "--motion", "walk", "--level", "4", "--speed", "1.5",
            "--reuse-simulation", str(made), "--out", str(tmp_path / "cap")]
    assert main(argv) == 1
    error = capsys.readouterr().err
    assert "dressing.level_mm: 12, not 4" in error and "motion_speed: 1.0, not 1.5" in error and "seed:" not in error
    assert not (tmp_path / "cap").exists()  # refused before anything was made
    argv = ["build", "--garment", "skirt", "--motions", "walk", "--seed", "2", "--reuse-simulation", f"walk={made}",
            "--out", str(tmp_path / "ds")]
    assert main(argv) == 1
    assert "seed: 0, not 2" in capsys.readouterr().err
    assert not (tmp_path / "ds" / "sim").exists()


def test_a_dataset_folder_missing_a_setting_is_refused_naming_it(tmp_path):
    """One record (`assets.fileio.record_stage`), no defaults filled in: a folder whose config.json lacks
    a setting (made before the setting existed) is refused, naming the setting with its new value."""
    _record(tmp_path, _config())
    _record(tmp_path, _config())  # the same settings: taken up
    saved = json.loads((tmp_path / "config.json").read_text())
    assert (saved["level_mm"], saved["motion_speed"]) == (12, 1.0)
    del saved["level_mm"], saved["motion_speed"]
    (tmp_path / "config.json").write_text(json.dumps(saved))
    with pytest.raises(ValueError, match=r"config.json: .*level_mm: \(none\) -> 12; motion_speed: \(none\) -> 1.0\)"):
        _record(tmp_path, _config())
    assert "level_mm" not in json.loads((tmp_path / "config.json").read_text())  # the record is kept


def test_a_smaller_fill_shows_smaller_markers_and_a_bad_one_is_refused(tmp_path, shirt_run, built, capsys):
    """`--fill`: the fixed camera backs off so the garment fills less of the image, and every marker
    shrinks by about the ratio (renders of small markers, where the localizer misses most)."""
    from assets.pattern.observation import ImageGroundTruth
    from factory.dataset import main

    reach = {}
    assert DatasetConfig.fill == 0.85  # the module's dataset is the default fill's
    for fill in (0.85, 0.5):
        out = built if fill == 0.85 else _seeded(tmp_path / f"fill{fill}", shirt_run)
        entries = [json.loads(line) for line in build(_config(fill=fill), out, progress=False).read_text().splitlines()]
        gts = [ImageGroundTruth.load(out / e["gt"]) for e in entries]
        corners = np.concatenate([g.points_px[g.status == 2] for g in gts])
        reach[fill] = np.median(np.linalg.norm(corners[:, 1:] - corners[:, :1], axis=-1))
        assert json.loads((out / "config.json").read_text())["fill"] == fill
    assert 0.5 < reach[0.5] / reach[0.85] < 0.7
    assert main(["build", "--garment", "shirt", "--motions", "walk", "--fill", "1.5", "--out", str(tmp_path / "bad")]) == 1
    assert "fill must be in (0, 1]" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_a_dataset_records_its_betas_and_refuses_a_rerun_with_others(tmp_path):
    plain, shaped = tmp_path / "plain", tmp_path / "shaped"
    _record(plain, _config())
    _record(shaped, _config(betas=(0.2, 0.4, 0.9)))
    assert json.loads((plain / "config.json").read_text())["betas"] is None
    assert json.loads((shaped / "config.json").read_text())["betas"] == [0.2, 0.4, 0.9]
    _record(shaped, _config(betas=(0.2, 0.4, 0.9)))  # the same settings: taken up
    for folder, other, change in ((plain, (0.2, 0.4, 0.9), r"\(none\) -> \[0.2, 0.4, 0.9\]"),
                                  (shaped, None, r"\[0.2, 0.4, 0.9\] -> \(none\)"),
                                  (shaped, (0.2, 0.4, 1.0), r"\[0.2, 0.4, 0.9\] -> \[0.2, 0.4, 1.0\]")):
        with pytest.raises(ValueError, match=rf"other settings or inputs \(betas: {change}\)"):
            _record(folder, _config(betas=other))
    with pytest.raises(ValueError, match=r"betas: expected 3 comma-separated numbers"):
        build(_config(betas=(0.5, 0.5)), tmp_path / "short", progress=False)
    assert not (tmp_path / "short").exists()


def test_every_simulation_of_a_dataset_and_a_capture_is_made_on_its_betas(tmp_path, capsys):
    from dataclasses import replace

    from factory.shards import simulation_of
    from factory.dataset import main

    config = replace(_config(betas=(0.2, 0.4, 0.9)), motions=("walk", "run"))
    assert {simulation_of(config, motion).betas for motion in config.motions} == {(0.2, 0.4, 0.9)}
    assert simulation_of(config, "walk").key() != simulation_of(_config(), "walk").key()
    assert simulation_of(_config(), "walk").betas is None  # the motion's own shape, else the body's default

    made = _finished_simulation(tmp_path, simulation_config("skirt", "walk", frames=3))
    for argv in (["capture", "--motion", "walk", "--reuse-simulation", str(made)],
                 ["build", "--motions", "walk", "--reuse-simulation", f"walk={made}"]):
        out = tmp_path / argv[0]
        assert main(argv + ["--garment", "skirt", "--betas", "0.2,0.4,0.9", "--out", str(out)]) == 1
        assert "betas: None, not [0.2, 0.4, 0.9]" in capsys.readouterr().err
        assert not (out / "sim").exists()


@pytest.mark.parametrize("command", [["build", "--motions", "walk"], ["capture", "--motion", "walk"]])
@pytest.mark.parametrize("betas, problem", [("0.5,0.5", "comma-separated numbers (gender, weight, height)"),
                                            ("0.5,heavy,0.5", "comma-separated numbers (gender, weight, height)"),
                                            ("nan,0.5,0.5", "comma-separated numbers (gender, weight, height)"),
                                            ("0.5,0.5,1.4", "height=1.4 is outside [0, 1]")])
def test_betas_that_do_not_fit_the_body_are_refused_before_anything_is_written(tmp_path, capsys, command, betas,
                                                                               problem):
    from factory.dataset import main

    out = tmp_path / "out"
    assert main(command + ["--garment", "shirt", "--betas", betas, "--out", str(out)]) == 1
    error = capsys.readouterr().err
    assert error.startswith("error: --betas: ") and problem in error, error
    assert not out.exists()


def test_the_cli_speaks_the_shared_vocabulary(tmp_path, capsys):
    """--device in the project's words (cpu, cuda) for Cycles, --workers only where it means something
    (Ray tasks at once), --out and --no-progress as every CLI has them; refusals before anything is made."""
    import argparse

    from factory.dataset import _render_settings, main

    def device(text):
        return _render_settings(argparse.Namespace(resolution=(64, 64), engine="CYCLES", samples=1, no_denoise=True,
                                                   device=text, texture_dpi=10.0)).device

    assert [device(d) for d in (None, "cpu", "CPU", "cuda", "gpu")] == ["auto", "CPU", "CPU", "GPU", "GPU"]
    out = tmp_path / "out"
    assert main(["capture", "--garment", "shirt", "--motion", "walk", "--device", "cuda:1", "--out", str(out)]) == 1
    assert "--device: expected one of cpu, cuda, gpu, auto for Cycles, got 'cuda:1'" in capsys.readouterr().err
    assert main(["build", "--garment", "shirt", "--motions", "walk", "--workers", "4", "--no-progress",
                 "--out", str(out)]) == 1
    assert "--workers sets the Ray tasks at once: give --backend ray" in capsys.readouterr().err
    assert not out.exists()
