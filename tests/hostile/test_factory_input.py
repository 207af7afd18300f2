"""Hostile and careless input to the factory: half-copied simulations, resumes from stale inputs or
rounded checkpoints, names that would become paths outside --out, sizes that would exhaust memory and
damaged files that used to end in a traceback.  The simulations are the default trousers on the 30 mm
level (dressed once per module, a few seconds) for a handful of frames."""

from __future__ import annotations

import argparse
import errno
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from assets.body import load_body
from assets.fileio import file_digest, load_npz, save_npz
from assets.motion.sources import load_motion
from factory import simulate as simulate_module
from factory.plan import reuse_simulation
from factory.dressing import DressingParams
from factory.simulate import SimulationConfig, simulate
from tests.hostile.conftest import assert_refused, files_under, run_cli

LEVEL_MM = 30  # the coarsest level every panel of the default trousers fits


def _config(motion: str = "walk", frames: int = 4, **changes) -> SimulationConfig:
    return SimulationConfig(garment="pants", motion=motion, frames=frames,
                            dressing=DressingParams(level_mm=LEVEL_MM), **changes)


@pytest.fixture(scope="module")
def pants_run(tmp_path_factory) -> Path:
    """A finished 4-frame simulation folder (sequence.npz, dressed.npz)."""
    out = tmp_path_factory.mktemp("pants_walk")
    simulate(_config(), out, progress=False)
    return out


def _dressed_folder(pants_run: Path, folder: Path) -> Path:
    """`folder` holding the module's dressing, so a simulation there starts at once."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(pants_run / "dressed.npz", folder / "dressed.npz")
    return folder


def _motion_file(path: Path, builtin: str) -> Path:
    load_motion(builtin, body=load_body("default"), seconds=3.0, fps=120.0).save(path)
    return path


# ---- half files ----------------------------------------------------------------------------------

@pytest.mark.hostile("half")
def test_a_full_disk_while_reusing_a_simulation_leaves_no_half_file_and_a_rerun_works(pants_run, tmp_path,
                                                                                      monkeypatch):
    real_copy = shutil.copyfile

    def copy_half_then_fill_the_disk(source, target, *args, **kwargs):
        data = Path(source).read_bytes()
        Path(target).write_bytes(data[:len(data) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    target = tmp_path / "sim" / "walk"
    monkeypatch.setattr(shutil, "copyfile", copy_half_then_fill_the_disk)
    with pytest.raises(OSError, match="sequence.npz"):
        reuse_simulation(pants_run, target, _config())
    assert not (target / "sequence.npz").exists()
    monkeypatch.setattr(shutil, "copyfile", real_copy)
    reuse_simulation(pants_run, target, _config())
    assert file_digest(target / "sequence.npz") == file_digest(pants_run / "sequence.npz")


# ---- resume ---------------------------------------------------------------------------------------

def _interrupt_after(monkeypatch, frames: int) -> None:
    """The next simulation stops (as if killed by Ctrl-C) while checking frame `frames` + 1."""
    real, calls = simulate_module._health, []

    def health(*args):
        calls.append(1)
        if len(calls) > frames:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(simulate_module, "_health", health)


@pytest.mark.hostile("stale")
def test_a_finished_run_whose_motion_file_changed_is_simulated_again(pants_run, tmp_path):
    motion = _motion_file(tmp_path / "motion.npz", "walk")
    out = _dressed_folder(pants_run, tmp_path / "run")
    config = _config(str(motion), frames=3)
    simulate(config, out, progress=False)
    _motion_file(motion, "wave")
    again = load_npz(simulate(config, out, progress=False))
    fresh = load_npz(simulate(config, _dressed_folder(pants_run, tmp_path / "fresh"), progress=False))
    np.testing.assert_array_equal(again["positions"], fresh["positions"])
    assert json.loads(str(again["meta"]))["config"]["inputs"]["motion"] == file_digest(motion)


@pytest.mark.hostile("stale")
def test_a_killed_run_whose_motion_file_changed_does_not_continue_the_old_frames(pants_run, tmp_path,
                                                                                  monkeypatch):
    motion = _motion_file(tmp_path / "motion.npz", "walk")
    out = _dressed_folder(pants_run, tmp_path / "run")
    config = _config(str(motion), frames=4, checkpoint_every=2)
    _interrupt_after(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt):
        simulate(config, out, progress=False)
    assert (out / "checkpoint.npz").exists()
    monkeypatch.undo()
    _motion_file(motion, "wave")
    resumed = load_npz(simulate(config, out, progress=False))["positions"]
    fresh = load_npz(simulate(config, _dressed_folder(pants_run, tmp_path / "fresh"), progress=False))["positions"]
    np.testing.assert_array_equal(resumed, fresh)


@pytest.mark.hostile("stale")
def test_a_dataset_whose_motion_file_changed_is_refused_naming_it(tmp_path):
    from factory.build import prepare
    from factory.plan import DatasetConfig, RenderSettings

    motion = _motion_file(tmp_path / "motion.npz", "walk")
    config = DatasetConfig(garment="pants", motions=(str(motion),), level_mm=LEVEL_MM,
                           render=RenderSettings(texture_dpi=10.0))
    prepare(config, tmp_path / "ds", (0, 1))
    _motion_file(motion, "wave")
    with pytest.raises(ValueError, match="motion.npz"):
        prepare(config, tmp_path / "ds", (0, 1))


@pytest.mark.hostile("silent")
@pytest.mark.parametrize("source", ["checkpoint", "shorter run"])
def test_a_resumed_simulation_is_bitwise_the_uninterrupted_one(pants_run, tmp_path, monkeypatch, source):
    whole = load_npz(simulate(_config(frames=6), _dressed_folder(pants_run, tmp_path / "whole"), progress=False))
    out = _dressed_folder(pants_run, tmp_path / "resumed")
    if source == "checkpoint":
        _interrupt_after(monkeypatch, 3)
        with pytest.raises(KeyboardInterrupt):
            simulate(_config(frames=6, checkpoint_every=2), out, progress=False)
        monkeypatch.undo()
    else:
        simulate(_config(frames=3), out, progress=False)
    resumed = load_npz(simulate(_config(frames=6), out, progress=False))
    for key in ("positions", "velocities"):
        assert np.array_equal(resumed[key], whole[key]), key


# ---- names that become paths ---------------------------------------------------------------------

@pytest.mark.hostile("outside")
@pytest.mark.parametrize("args", [["--motions", "../../x"], ["--motions", "walk", "--reuse-simulation", "../../x=SIM"]],
                         ids=["motions", "reuse-simulation"])
def test_a_motion_name_cannot_lead_outside_the_output_folder(pants_run, tmp_path, args):
    root = tmp_path / "root"
    out = root / "a" / "out"
    out.parent.mkdir(parents=True)
    args = [a.replace("SIM", str(pants_run)) for a in args]
    result = run_cli("factory.dataset", "build", "--garment", "pants", "--level", LEVEL_MM, *args,
                     "--texture-dpi", 10, "--out", out)
    assert_refused(result, "../../x")
    assert [p for p in root.rglob("*") if out not in (p, *p.parents)] == [out.parent]


# ---- memory bombs --------------------------------------------------------------------------------

@pytest.mark.hostile("memory")
@pytest.mark.parametrize("module, args, needle", [
    ("factory.dataset", ["build", "--motions", "walk", "--resolution", "100000x100000"], "--resolution"),
    ("factory.dataset", ["build", "--motions", "walk", "--frames", "100000000"], "--frames"),
    ("factory.dataset", ["build", "--motions", "walk", "--variations", "1000000000"], "--variations"),
    ("factory.dataset", ["build", "--motions", "walk", "--samples", "1000000000"], "--samples"),
    ("factory.dataset", ["capture", "--motion", "walk", "--cameras", "100000000"], "--cameras"),
    ("factory.dataset", ["capture", "--motion", "walk", "--resolution", "100000x100000"], "--resolution"),
    ("factory.simulate", ["--motion", "walk", "--frames", "1000000000"], "--frames"),
], ids=["build-resolution", "build-frames", "build-variations", "build-samples", "capture-cameras",
        "capture-resolution", "simulate-frames"])
def test_a_size_beyond_reason_is_refused_before_anything_is_made(tmp_path, module, args, needle):
    result = run_cli(module, *args, "--garment", "pants", "--level", LEVEL_MM, "--out", tmp_path / "out",
                     mem_gib=3.0, timeout=120)
    assert_refused(result, needle, "--max-")
    assert not (tmp_path / "out").exists()


@pytest.mark.hostile("memory")
def test_a_limit_can_be_raised():
    from factory.limits import limits_from_args

    limits = limits_from_args(argparse.Namespace(max_pixels=1e10))
    limits.check("pixels", 100000 * 100000, "an image", "--resolution")
    with pytest.raises(ValueError, match="--max-pixels"):
        limits.check("pixels", 2e10, "an image", "--resolution")
    with pytest.raises(ValueError, match="--max-samples must be"):
        limits_from_args(argparse.Namespace(max_samples=float("nan")))


# ---- damaged files -------------------------------------------------------------------------------

def _damage(kind: str, out: Path, pants_run: Path) -> list[str]:
    """Write a damaged file of `kind` into the output folder `out`; the extra arguments it needs."""
    sequence = load_npz(pants_run / "sequence.npz")
    if "dressing" not in kind:
        _dressed_folder(pants_run, out)
    out.mkdir(parents=True, exist_ok=True)
    if kind == "empty sequence":
        (out / "sequence.npz").write_bytes(b"")
    elif kind == "sequence without positions":
        save_npz(out / "sequence.npz", {k: v for k, v in sequence.items() if k != "positions"})
    elif kind == "sequence with 0-d positions":
        save_npz(out / "sequence.npz", {**sequence, "positions": np.array(1.0)})
    elif kind == "sequence with flat positions":
        save_npz(out / "sequence.npz", {**sequence, "positions": sequence["positions"][..., :2]})
    elif kind == "sequence with a broken meta":
        save_npz(out / "sequence.npz", {**sequence, "meta": np.array("{not json")})
    elif kind == "empty dressing":
        (out / "dressed.npz").write_bytes(b"")
    elif kind == "dressing without its meta fields":
        dressed = load_npz(pants_run / "dressed.npz")
        save_npz(out / "dressed.npz", {**dressed, "meta": np.array("{}")})
    elif kind == "motion with wrong shapes":
        motion = load_npz(_motion_file(out.parent / "motion.npz", "walk"))
        save_npz(out.parent / "motion.npz", {**motion, "poses": motion["poses"][:, :5]})
        return ["--motion", out.parent / "motion.npz"]
    return ["--motion", "walk"]


@pytest.mark.hostile("traceback")
@pytest.mark.parametrize("kind", ["empty sequence", "sequence without positions", "sequence with 0-d positions",
                                  "sequence with flat positions", "sequence with a broken meta", "empty dressing",
                                  "dressing without its meta fields", "motion with wrong shapes"])
def test_a_damaged_file_is_named_without_a_traceback(pants_run, tmp_path, kind):
    out = tmp_path / "out"
    args = _damage(kind, out, pants_run)
    result = run_cli("factory.simulate", "--garment", "pants", "--level", LEVEL_MM, "--frames", 4, *args,
                     "--out", out, "--no-preview", timeout=120)
    file = "motion.npz" if kind.startswith("motion") else "dressed.npz" if "dressing" in kind else "sequence.npz"
    assert_refused(result, file)


@pytest.mark.hostile("traceback")
@pytest.mark.parametrize("content", ["", "[1, 2]", "{\"garment\": "])
def test_a_corrupt_dataset_config_is_named_without_a_traceback(tmp_path, content):
    out = tmp_path / "out"
    out.mkdir()
    (out / "config.json").write_text(content)
    result = run_cli("factory.dataset", "build", "--garment", "pants", "--motions", "walk", "--level", LEVEL_MM,
                     "--texture-dpi", 10, "--out", out, timeout=120)
    assert_refused(result, "config.json")


@pytest.mark.hostile("traceback")
def test_a_reused_simulation_with_a_broken_meta_is_named(pants_run, tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    save_npz(source / "sequence.npz", {**load_npz(pants_run / "sequence.npz"), "meta": np.array("[broken")})
    with pytest.raises(ValueError, match=r"sequence.npz: meta"):
        reuse_simulation(source, tmp_path / "target", _config())


@pytest.mark.hostile("stale")
def test_a_capture_rerun_after_its_motion_file_changed_is_refused(tmp_path):
    """Its images would be of the old motion beside ground truth of the new one."""
    from factory.capture import capture
    from factory.plan import RenderSettings

    motion = _motion_file(tmp_path / "motion.npz", "walk")
    options = dict(frames=1, first_frame=1, cameras=1, resolution=(48, 32), level_mm=LEVEL_MM, progress=False,
                   render=RenderSettings(engine="WORKBENCH", samples=1, denoise=False, texture_dpi=10.0))
    out = capture("pants", str(motion), tmp_path / "cap", **options)
    rendered = files_under(out / "cam00")
    capture("pants", str(motion), out, **options)  # the same capture: nothing to do
    _motion_file(motion, "wave")
    with pytest.raises(ValueError, match=r"capture.json: .*(inputs|simulation)"):
        capture("pants", str(motion), out, **options)
    with pytest.raises(ValueError, match=r"capture.json: .*cameras"):
        capture("pants", "walk", out, **{**options, "cameras": 2})
    assert files_under(out / "cam00") == rendered
