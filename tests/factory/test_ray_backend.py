"""The dataset build as Ray tasks on a local Ray instance of 2 CPUs: the same dataset as the local
backend, byte for byte, also when a worker dies in mid-shard (a real process exit, retried by Ray)."""

import json
from pathlib import Path

import pytest

from factory.build import build
from factory.plan import DatasetConfig, RenderSettings
from factory.shards import CRASH_ONCE_ENV
from tests.factory.test_dataset import _seeded

pytest.importorskip("ray")
pytestmark = pytest.mark.slow

TINY = RenderSettings(resolution=(48, 48), engine="WORKBENCH", samples=1, denoise=False)
CONFIG = DatasetConfig(garment="shirt", motions=("walk",), frame_list=(2, 4), variations=1, render=TINY)


def _outputs(root: Path) -> list[Path]:
    """The dataset, not the work files (sim, jobs, timing) nor a killed writer's hidden temporary."""
    return sorted(p.relative_to(root) for p in root.rglob("*") if p.is_file() and not p.name.startswith(".")
                  and not {"sim", "jobs"} & set(p.relative_to(root).parts) and p.name != "timing.json")


def _assert_same_dataset(expected: Path, got: Path) -> None:
    files = _outputs(expected)
    assert files == _outputs(got)
    for f in files:
        assert (expected / f).read_bytes() == (got / f).read_bytes(), f


@pytest.fixture(scope="module")
def local_build(tmp_path_factory, shirt_run):
    out = _seeded(tmp_path_factory.mktemp("local") / "ds", shirt_run)
    build(CONFIG, out, progress=False)
    return out


def test_a_ray_build_makes_the_local_backends_dataset(tmp_path, local_build, shirt_run):
    out = _seeded(tmp_path / "ds", shirt_run)
    manifest = build(CONFIG, out, progress=False, backend="ray", workers=2)
    assert len(manifest.read_text().splitlines()) == 2
    _assert_same_dataset(local_build, out)
    timing = json.loads((out / "timing.json").read_text())
    assert (timing["images"], timing["retried"]) == (2, 0)
    build(CONFIG, out, progress=False, backend="ray", workers=2)  # restarted: nothing left to make
    assert json.loads((out / "timing.json").read_text())["images"] == 0
    _assert_same_dataset(local_build, out)


def test_a_worker_killed_in_mid_shard_is_retried_and_leaves_no_partial_record(tmp_path, local_build, shirt_run,
                                                                                monkeypatch):
    crashed = tmp_path / "crashed"
    monkeypatch.setenv(CRASH_ONCE_ENV, str(crashed))  # the local Ray instance's workers inherit it
    out = _seeded(tmp_path / "ds", shirt_run)
    manifest = build(CONFIG, out, progress=False, backend="ray", workers=2)
    assert crashed.exists()  # a worker did exit in mid-shard, after writing an image's ground truth
    names = [json.loads(line)["name"] for line in manifest.read_text().splitlines()]
    assert sorted(names) == sorted(set(names)) and len(names) == 2
    assert json.loads((out / "timing.json").read_text())["retried"] == 1
    _assert_same_dataset(local_build, out)
