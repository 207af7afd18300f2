"""The dataset build (`python -m factory.dataset build`): settings record, tasks, backends, resume.

`build(config, out, shard=(i, n))` makes (or finishes) shard i of n of the dataset that a
`factory.plan.DatasetConfig` describes, in the folder `out` (its layout: `factory.dataset`):

1. `prepare`: the folder's ``config.json`` (`assets.fileio.record_stage`: a rerun with other settings
   or other input files is refused, naming them), reused simulations taken up, the template and its
   texture.
2. One simulation task per motion (`factory.shards.simulate_motion`: `factory.simulate`, which takes
   up or continues what ``sim/<motion>/`` holds).
3. `factory.shards.plan_shards`: the fixed camera, ``splits.json``, ``scenes/<motion>.npz`` and the
   unfinished images of this shard, grouped `shard_frames` frames of one motion per `Shard`.
4. One render + ground-truth task per `Shard` (`factory.shards.make_shard`; an image is done when its
   record ``meta/<name>.json`` exists, written last).
5. ``timing.json``, ``manifest.jsonl`` rewritten from ``meta/`` (`write_manifest`), ``contact_sheet.png``.

Resume: a rerun plans only the images without a record, so a killed build continues where it stopped,
and several processes (or machines sharing the folder) can work on the shards of one dataset at once;
each rewrites the manifest when it finishes.  A backend runs the tasks: `LocalBackend` one after the
other in this process, `factory.raybackend.RayBackend` as Ray tasks with retries (`--backend ray`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict
from pathlib import Path

from assets.fileio import record_stage, save_json
from factory.plan import DatasetConfig, check_betas, input_record, reuse_simulation
from factory.preview import preview
from factory.scenes import render_template
from factory.shards import (BuildProgress, Shard, make_shard, motion_labels, plan_shards, simulate_motion,
                            simulation_of, write_manifest)
from factory.simulate import input_digests

log = logging.getLogger(__name__)


def config_record(config: DatasetConfig) -> dict:
    """What ``config.json`` records of a dataset: its settings, and the SHA-256 of each input given as a
    file ("inputs.garment", "inputs.body", "inputs.motion <spec>"), so a file changed since is seen."""
    return {**asdict(config), **input_record(input_digests(garment=config.garment, body=config.body,
                                                           **{f"motion {m}": m for m in config.motions}))}


def prepare(config: DatasetConfig, out: Path, shard: tuple[int, int],
            simulations: dict[str, str | Path] | None = None) -> None:
    """Check the arguments and the folder's settings; take up reused simulations; write the template
    and its texture.  Everything the tasks read that is not per motion is on disk after this."""
    index, count = shard
    if not 0 <= index < count:
        raise ValueError(f"shard must be i/n with 0 <= i < n, got {index}/{count}")
    if config.variations < 1:
        raise ValueError(f"variations must be >= 1, got {config.variations}")
    if not 0 < config.fill <= 1 or not 5 <= config.fov_deg <= 120:
        raise ValueError(f"fill must be in (0, 1] and fov_deg in [5, 120], got {config.fill} and {config.fov_deg}")
    check_betas(config.betas, config.body)
    labels = motion_labels(config.motions)
    for motion in simulations or {}:
        if motion not in config.motions:
            raise ValueError(f"--reuse-simulation {motion!r}=DIR: {motion!r} is not one of --motions "
                             f"({', '.join(config.motions)})")
    # a folder holding a dataset of other settings or input files is refused, naming them: its
    # images would not match
    record_stage(out / "config.json", config_record(config))
    for motion, folder in (simulations or {}).items():
        reuse_simulation(folder, out / "sim" / labels[motion], simulation_of(config, motion))
    template = render_template(config.garment, config.render.texture_dpi, out)
    if not (out / "template.npz").exists():
        template.save(out / "template.npz", levels=(config.level_mm,))


class LocalBackend:
    """Every task in this process, one after the other (`--shard i/n` spreads a build over processes)."""

    def __enter__(self) -> "LocalBackend":
        return self

    def __exit__(self, *exc) -> None:
        return None

    def simulate(self, config: DatasetConfig, out: Path, bar: BuildProgress) -> dict[str, Path]:
        sequences = {}
        for motion in config.motions:
            sequences[motion] = simulate_motion(config, out, motion)
            bar.done()
        return sequences

    def make_shards(self, config: DatasetConfig, out: Path, shards: list[Shard], bar: BuildProgress) -> list[dict]:
        timings = []
        for shard in shards:
            timings.append(make_shard(config, out, shard))
            bar.done(timings[-1]["images"])
        return timings


BACKENDS = ("local", "ray")


def build(config: DatasetConfig, out: str | Path, shard: tuple[int, int] = (0, 1), progress: bool = True,
          simulations: dict[str, str | Path] | None = None, backend: str = "local", address: str | None = None,
          workers: int | None = None, shard_frames: int = 1) -> Path:
    """Build (or resume) shard `shard` = (i, n) of the dataset in `out`; returns the manifest path.
    `simulations`: motion -> a finished simulation folder to reuse.  `backend`: "local" (this
    process) or "ray" (`factory.raybackend`: tasks on the Ray cluster at `address`, or on a local Ray
    instance running `workers` tasks at once, default one per core); both run the same tasks: one
    simulation per motion, then one render + ground-truth `Shard` per `shard_frames` frames.  ``timing.json`` gets the images made,
    the failed task attempts retried and the times (wall, scene set-up, render, ground truth).  Ends
    with ``contact_sheet.png`` of a few finished images with their ground truth."""
    out = Path(out)
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    prepare(config, out, shard, simulations)
    if backend == "ray":
        from factory.raybackend import RayBackend

        runner = RayBackend(address, workers)
    else:
        runner = LocalBackend()
    bar = BuildProgress(progress)
    try:
        with runner:
            bar.add(len(config.motions))
            sequences = runner.simulate(config, out, bar)
            shards = plan_shards(config, out, sequences, shard, shard_frames)
            bar.add(len(shards))
            timings = runner.make_shards(config, out, shards, bar)
    finally:
        bar.close()
    timing = {key: sum(t[key] for t in timings) for key in ("images", "setup_s", "render_s", "groundtruth_s")}
    timing.update(retried=bar.retried, wall_s=time.perf_counter() - bar.started)
    save_json(out / "timing.json", timing)
    log.info("%d images made, %d failed task attempts retried, %.0f s", timing["images"], timing["retried"],
             timing["wall_s"])
    manifest = write_manifest(out)
    if manifest.read_text().strip():
        preview(out, out / "contact_sheet.png")
    return manifest
