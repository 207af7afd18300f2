"""Simulate a garment on a body through a motion: the factory's simulator.

    python -m factory.simulate --garment shirt --motion walk --body default --frames 240 --out out/sim

The garment is dressed on the body (`factory.dressing`, cached as ``dressed.npz`` in the output
folder), the motion is resampled to 1 / timestep (120 Hz) and led in by a transition from the
dressing pose, and the cloth (`factory.cloth`) follows the body frame by frame.  Frame 0 is the
dressed garment at the transition's start.

Output folder:
  sequence.npz     positions (T, V, 3) float32, faces (F, 3) int32 (the sewn mesh of the template
                   level), body_poses (T, 24, 3), body_trans (T, 3), body_betas, fps, the last
                   frame's state as the run keeps it (state_positions, velocities (V, 3) float64: a
                   longer rerun continues it bitwise as an uninterrupted run), and `meta`
                   (JSON: garment, level, motion, body, shape, cloth and dressing parameters, seed,
                   the SHA-256 of every input given as a file, transition frames, timing and health)
  checkpoint.npz   while running: the frames so far and the last frame's state, written atomically every
                   `checkpoint_every` frames; a rerun of the same simulation (same options, same input
                   files' content) resumes from it, another one starts over
  dressed.npz      the dressed garment (reused by reruns with the same garment, body and dressing,
                   and through a shared `dressings` folder by the other motions of a dataset)
  preview.png      a few frames of body and garment

Health: after every frame, no NaN, the deepest vertex inside the body under `max_penetration` and the
largest edge strain under `max_strain`; a failing frame stops the run with `SimulationError` naming
it, and the frames before it stay in ``checkpoint.npz``.  A vertex caught where the body intersects
itself (`MeshCollider.in_fold`: the `jump`'s hip crease at frame 191) has no position outside the
body: it is left out of the penetration and counted as folded (the health's third column).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import hashlib
import json
import logging
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from assets.body import load_body
from assets.body.model import BodyModel
from assets.cli import add_out, add_progress, progress, run_cli
from assets.fileio import file_digest, load_npz, save_npz
from assets.garments import Template
from assets.garments.loading import load_template
from assets.motion.motion import Motion, body_poses, motion_betas, resample, with_transition
from assets.motion.sources import load_motion
from factory.cloth import ClothModel, ClothParams, ClothState, MeshCollider, ProjectiveDynamics
from factory.dressing import DressedGarment, DressingError, DressingParams, dress
from factory.limits import add_limit_options, limits_from_args

log = logging.getLogger(__name__)


class SimulationError(RuntimeError):
    """A frame failed its health check (or the inputs cannot be simulated)."""


@dataclass(frozen=True)
class HealthLimits:
    #: deepest a vertex may be inside the body (m)
    max_penetration: float = 0.01
    #: largest edge strain (length / rest length - 1)
    max_strain: float = 1.0


@dataclass(frozen=True)
class SimulationConfig:
    garment: str
    motion: str
    body: str = "default"
    frames: int = 240
    betas: tuple[float, ...] | None = None
    seed: int = 0
    transition_seconds: float = 1.0
    motion_speed: float = 1.0
    cloth: ClothParams = field(default_factory=ClothParams)
    dressing: DressingParams = field(default_factory=DressingParams)
    health: HealthLimits = field(default_factory=HealthLimits)
    checkpoint_every: int = 24

    def key(self) -> str:
        """What makes two runs the same simulation (resume only continues an identical one): the
        options and the content of the input files; length, checkpointing and health limits do not
        change the frames."""
        return _digest(self._keyed())

    def inputs(self) -> dict[str, str]:
        """The SHA-256 of each input given as a file (garment pattern or template, motion, body), by
        option; a built-in garment or motion and the default body have none: the config is their
        content."""
        return input_digests(garment=self.garment, motion=self.motion, body=self.body)

    def record(self) -> dict:
        """The config as JSON for ``meta["config"]``, with `inputs` when any input is a file."""
        inputs = self.inputs()
        return json.loads(json.dumps({**asdict(self), **({"inputs": inputs} if inputs else {})}, default=str))

    def _keyed(self) -> dict:
        data = self.record()
        for name in _NOT_KEYED:
            data.pop(name)
        return data

    def differences(self, recorded: dict) -> list[str]:
        """The options in which a simulation recorded with config `recorded` (its ``meta["config"]``) is
        another simulation than this one's, as "name: recorded value, not this value" (nested options
        dotted: "dressing.level_mm")."""
        return _differences({k: v for k, v in recorded.items() if k not in _NOT_KEYED}, self._keyed())


#: the options of a `SimulationConfig` that do not change its frames (not in its key)
_NOT_KEYED = ("frames", "checkpoint_every", "health")


def _differences(recorded: dict, wanted: dict, prefix: str = "") -> list[str]:
    found = []
    for name in sorted(set(recorded) | set(wanted)):
        a, b = recorded.get(name), wanted.get(name)
        if isinstance(a, dict) and isinstance(b, dict):
            found += _differences(a, b, f"{prefix}{name}.")
        elif a != b:
            found.append(f"{prefix}{name}: {a!r}, not {b!r}")
    return found


def input_digests(**specs: str) -> dict[str, str]:
    """{name: SHA-256} of the `specs` (garment, motion, body...) that name a file; names of built-ins
    have no entry.  A resumed stage compares these, so an input replaced under the same path is seen."""
    found = {}
    for name, spec in specs.items():
        path = Path(spec)
        if path.is_file():
            stat = path.stat()
            found[name] = _cached_digest(str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    return found


@functools.lru_cache(maxsize=64)
def _cached_digest(path: str, size: int, mtime_ns: int) -> str:
    # size and modification time in the cache key: a file rewritten in place is hashed again
    return file_digest(path)


def _digest(value: object) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:16]


@dataclass
class FrameHealth:
    bad_vertices: int  # NaN or infinite
    penetration: float  # deepest vertex inside the body, the folded ones left out (m)
    strain: float
    folded: int = 0  # vertices deeper than the cloth's fold_depth where the body intersects itself


def load_simulation_motion(config: SimulationConfig, body: BodyModel) -> Motion:
    """The motion at 1 / timestep (120 Hz), long enough for `config.frames` after the transition."""
    fps = 1.0 / config.cloth.timestep
    needed = config.frames / fps - config.transition_seconds + 0.5
    # built-in motions in whole 10 s blocks, so runs of different lengths (a resumed, longer run)
    # share their first frames exactly
    seconds = 10.0 * max(1, int(np.ceil(needed / 10.0)))
    motion = load_motion(config.motion, body=body, seconds=seconds, speed=config.motion_speed, fps=fps)
    return motion if abs(motion.fps - fps) < 1e-9 else resample(motion, fps)


def with_dressing_transition(config: SimulationConfig, motion: Motion, dressed: DressedGarment) -> Motion:
    """`motion` led in from the dressing pose, `config.frames` long.  The body starts in the dressing
    pose at the motion's first (x, y) and the dressing height."""
    fps = 1.0 / config.cloth.timestep
    transition = config.transition_seconds
    start = np.array([motion.trans[0, 0], motion.trans[0, 1], dressed.body_trans[2]])
    motion = with_transition(motion, dressed.dressing_pose, transition, start_trans=start)
    if motion.num_frames < config.frames:
        raise SimulationError(f"motion '{config.motion}' gives {motion.num_frames} frames at {fps:g} Hz with the "
                              f"transition; {config.frames} were asked for")
    return motion.frames(0, config.frames)


def _dressed(config: SimulationConfig, template: Template, body: BodyModel, betas, out: Path,
             progress: bool, dressings: Path | None = None) -> DressedGarment:
    """The garment dressed on the body: ``out/dressed.npz`` when it holds this dressing, else
    ``dressings/<key>.npz`` (copied to `out`), else dressed anew and saved to both."""
    path = out / "dressed.npz"
    inputs = input_digests(garment=config.garment, body=config.body)
    key = _digest([config.garment, config.body, list(np.asarray(betas, float)), asdict(config.dressing)]
                  + ([inputs] if inputs else []))  # (built-in inputs keep the keys of earlier dressings)
    shared = None if dressings is None else Path(dressings) / f"{key}.npz"
    for source in (path, shared):
        if source is not None and source.exists():
            cached = DressedGarment.load(source)
            if cached.report.get("key") == key:
                log.info("reusing the dressing %s", source)
                for target in (path, shared):
                    if target is not None and not target.exists():
                        cached.save(target)
                return cached
    garment = dress(template, body, betas, config.dressing, progress=progress)
    garment = dataclasses.replace(garment, report={**garment.report, "key": key})
    garment.save(path)
    if shared is not None:
        garment.save(shared)
    return garment


def simulate(config: SimulationConfig, out: str | Path, progress: bool = True,
             dressings: str | Path | None = None) -> Path:
    """Run (or resume) the simulation into folder `out`; returns the path of ``sequence.npz``.
    `dressings`: a folder of dressed garments by key that the simulations of other motions share (a
    dataset's motions are dressed alike: one dressing instead of one per motion)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if config.frames < 1:
        raise ValueError(f"frames must be >= 1, got {config.frames}")
    body = load_body(config.body)
    template = load_template(config.garment)
    motion = load_simulation_motion(config, body)
    if config.betas is not None:
        betas = np.asarray(config.betas, np.float64)
    else:
        own = motion_betas(body, motion)
        betas = body.default_betas if own is None else own
    sequence_path, checkpoint_path = out / "sequence.npz", out / "checkpoint.npz"
    key = config.key()
    if sequence_path.exists():
        done = load_npz(sequence_path, required=("positions", "meta"))
        if read_meta(sequence_path, done).get("key") == key \
                and len(_checked_positions(sequence_path, done)) >= config.frames:
            log.info("%s already holds %d frames of this simulation", sequence_path, len(done["positions"]))
            return sequence_path
    try:
        dressed = _dressed(config, template, body, betas, out, progress, dressings)
    except DressingError as exc:
        raise SimulationError(str(exc)) from exc
    motion = with_dressing_transition(config, motion, dressed)
    poses = body_poses(body, motion)
    offset = motion.trans[0] - dressed.body_trans

    model = ClothModel.build(dressed.faces, dressed.rest_corners, config.cloth)
    solver = ProjectiveDynamics(model)
    positions = np.zeros((config.frames, model.num_vertices, 3), np.float32)
    state = ClothState(dressed.positions + offset, np.zeros_like(dressed.positions))
    positions[0] = state.positions
    start, health = 1, []
    resume_from = checkpoint_path if checkpoint_path.exists() else sequence_path  # a shorter finished run
    if resume_from.exists():
        saved = load_npz(resume_from, required=("positions", "meta"))
        saved_meta = read_meta(resume_from, saved)
        if saved_meta.get("key") != key:
            differ = config.differences(saved_meta.get("config", {})) if isinstance(saved_meta.get("config"), dict) \
                else []
            log.warning("%s is from a different simulation (%s); starting over", resume_from,
                        "; ".join(differ) or "another version of the simulator")
        elif "state_positions" not in saved or len(_checked_positions(resume_from, saved)) > config.frames:
            # the exact state is kept for the last frame only (and not by earlier versions)
            log.warning("%s holds no exact state of frame %d to continue from; starting over", resume_from,
                        config.frames)
        else:
            _check_state(resume_from, saved, positions.shape[1:])
            start = len(saved["positions"])
            positions[:start] = saved["positions"]
            state = ClothState(saved["state_positions"], saved["velocities"])
            health = saved_meta.get("health", [])[:start]
            log.info("resuming %s from frame %d", out, start)

    meta = {
        "key": key, "garment": template.name, "garment_spec": config.garment, "level_mm": dressed.level_mm,
        "motion": config.motion, "motion_name": motion.name, "body": config.body, "body_betas": list(map(float, betas)),
        "fps": 1.0 / config.cloth.timestep, "transition_frames": int(round(config.transition_seconds / config.cloth.timestep)),
        "seed": config.seed, "config": config.record(),
        "dressing": dressed.report, "health_limits": asdict(config.health),
    }

    def save_checkpoint(frames: int) -> None:
        # the state as the run keeps it (float64), so a resumed run is bitwise the uninterrupted one
        save_npz(checkpoint_path, {"positions": positions[:frames], "state_positions": state.positions,
                                   "velocities": state.velocities,
                                   "meta": np.array(json.dumps({**meta, "health": health}))})

    started = time.perf_counter()
    bar = tqdm(total=config.frames, initial=start, desc=f"simulating {template.name}", unit="frame",
               disable=not progress)
    for frame in range(start, config.frames):
        # posed one frame at a time: a batched pose rounds differently with the batch's length, and a
        # resumed run must meet the body an uninterrupted one met
        collider = MeshCollider(body.pose(poses[frame], motion.trans[frame:frame + 1], betas).vertices[0], body.faces)
        stepped = solver.step(state, collider)
        check = _health(model, collider, stepped.positions)
        problem = _problem(check, config.health)
        if problem:  # kept: the frames before it, with the last of them's velocities (`state`), to resume from
            save_checkpoint(frame)
            bar.close()
            raise SimulationError(f"frame {frame} of {out}: {problem}; frames 0..{frame - 1} are kept in {checkpoint_path}")
        state = stepped
        positions[frame] = state.positions
        health.append([check.penetration, check.strain, check.folded])
        bar.update()
        bar.set_postfix(pen_mm=f"{check.penetration * 1e3:.1f}", strain=f"{check.strain:.3f}", folded=check.folded)
        if (frame + 1) % config.checkpoint_every == 0:
            save_checkpoint(frame + 1)
    bar.close()
    elapsed = time.perf_counter() - started
    simulated = config.frames - start
    meta["seconds_per_frame"] = elapsed / simulated if simulated else None
    meta["max_penetration_mm"] = 1e3 * max((h[0] for h in health), default=0.0)
    meta["max_strain"] = max((h[1] for h in health), default=0.0)
    meta["folded_frames"] = sum(1 for h in health if h[2])
    save_npz(sequence_path, {
        "positions": positions, "state_positions": state.positions, "velocities": state.velocities,
        "faces": dressed.faces.astype(np.int32), "body_poses": motion.poses,
        "body_trans": motion.trans, "body_betas": np.asarray(betas, np.float64), "fps": np.array(meta["fps"]),
        "meta": np.array(json.dumps({**meta, "health": health})),
    })
    checkpoint_path.unlink(missing_ok=True)
    log.info("%s: %d frames, %.3f s per frame, max penetration %.2f mm, max strain %.3f", sequence_path,
             config.frames, meta["seconds_per_frame"] or 0.0, meta["max_penetration_mm"], meta["max_strain"])
    return sequence_path


def read_meta(path: Path, arrays: dict[str, np.ndarray]) -> dict:
    """The `meta` JSON object of a simulation file's `arrays` (read from `path`, named in errors)."""
    try:
        meta = json.loads(str(arrays["meta"]))
    except (KeyError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: meta is not a JSON object ({exc})") from exc
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: meta is not a JSON object (got {type(meta).__name__})")
    return meta


def _checked_positions(path: Path, arrays: dict[str, np.ndarray]) -> np.ndarray:
    """The `positions` of a simulation file's `arrays`: (T, V, 3) finite floats, or a ValueError naming `path`."""
    positions = arrays["positions"]
    if positions.ndim != 3 or positions.shape[2] != 3 or not np.issubdtype(positions.dtype, np.floating) \
            or not np.isfinite(positions).all():
        raise ValueError(f"{path}: positions has shape {positions.shape} ({positions.dtype}), expected finite "
                         "floats of shape (T, V, 3)")
    return positions


def _check_state(path: Path, saved: dict[str, np.ndarray], frame_shape: tuple[int, int]) -> None:
    """A checkpoint or shorter run that `simulate` continues: positions (T, V, 3), state_positions and
    velocities (V, 3), finite, V that of the garment being simulated."""
    expected = {"positions": (None, *frame_shape), "state_positions": frame_shape, "velocities": frame_shape}
    for name, shape in expected.items():
        array = saved.get(name)
        if array is None:
            raise ValueError(f"{path}: missing array {name}")
        if array.ndim != len(shape) or any(n is not None and n != m for n, m in zip(shape, array.shape)) \
                or not np.issubdtype(array.dtype, np.floating) or not np.isfinite(array).all():
            raise ValueError(f"{path}: {name} has shape {array.shape} ({array.dtype}), expected finite floats of "
                             f"shape {tuple('T' if n is None else n for n in shape)}")
    if not len(saved["positions"]):
        raise ValueError(f"{path}: positions holds no frame")


def _health(model: ClothModel, collider: MeshCollider, x: np.ndarray) -> FrameHealth:
    bad = int((~np.isfinite(x)).any(axis=1).sum())
    if bad:
        return FrameHealth(bad, float("nan"), float("nan"))
    d, _ = collider.signed_distance(x)
    deep = np.flatnonzero(d < -model.params.fold_depth)  # the contact projection leaves only these inside
    folded = deep[collider.in_fold(x[deep])]
    d[folded] = 0.0
    return FrameHealth(0, float(max(0.0, -d.min())), float(np.abs(model.edge_length_strain(x)).max()), len(folded))


def _problem(check: FrameHealth, limits: HealthLimits) -> str:
    if check.bad_vertices:
        return f"{check.bad_vertices} vertices are NaN or infinite"
    if check.penetration > limits.max_penetration:
        return f"a vertex is {check.penetration * 1e3:.1f} mm inside the body (limit {limits.max_penetration * 1e3:.1f} mm)"
    if check.strain > limits.max_strain:
        return f"an edge is strained {check.strain:.2f} (limit {limits.max_strain:.2f})"
    return ""


def write_preview(sequence_path: str | Path, png: str | Path, body: BodyModel | None = None, frames: int = 4) -> None:
    """Draw a few frames of a simulated sequence (body and garment) into a PNG."""
    from assets.motion.export import preview_frames, render_preview

    data = load_npz(sequence_path, required=("positions", "faces", "body_poses", "body_trans", "body_betas", "meta"))
    meta = json.loads(str(data["meta"]))
    body = body or load_body(meta["body"])
    pick = preview_frames(frames, len(data["positions"]))
    posed = body.pose(data["body_poses"][pick], data["body_trans"][pick], data["body_betas"])
    render_preview(png, posed, frames=np.arange(len(pick)), labels=[f"frame {t}" for t in pick],
                   title=f"{meta['garment']} on {meta['motion']}",
                   extra=((data["positions"][pick], data["faces"], (0.25, 0.45, 0.85)),))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m factory.simulate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--garment", required=True, help="default garment name, pattern JSON or template .npz")
    parser.add_argument("--motion", required=True, help="built-in motion, AMASS .npz, motion .npz or .bvh")
    parser.add_argument("--body", default="default", help="'default' or an SMPL-family model file")
    parser.add_argument("--betas", help="body shape, comma-separated (default: the body's default)")
    parser.add_argument("--frames", type=int, default=240, help="frames at 120 Hz, the transition included")
    add_out(parser, "output folder (resumes what is there when it is this simulation's; starts over otherwise)")
    parser.add_argument("--level", type=int, default=DressingParams.level_mm, help="template level (mm)")
    parser.add_argument("--pose", choices=("A", "T"), default=DressingParams.pose, help="dressing pose")
    parser.add_argument("--transition-seconds", type=float, default=1.0)
    parser.add_argument("--speed", type=float, default=1.0, help="built-in motions: speed multiplier")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--iterations", type=int, default=ClothParams.iterations, help="local-global iterations per step")
    parser.add_argument("--contact-cg-iterations", type=int, default=ClothParams.contact_cg_iterations,
                        help="conjugate-gradient iterations per global step for the sliding contact")
    for name in ("membrane_weight", "bending_weight", "density", "contact_weight", "contact_radius"):
        parser.add_argument("--" + name.replace("_", "-"), type=float, default=getattr(ClothParams, name))
    parser.add_argument("--max-penetration-mm", type=float, default=HealthLimits.max_penetration * 1e3)
    parser.add_argument("--max-strain", type=float, default=HealthLimits.max_strain)
    parser.add_argument("--no-preview", action="store_true")
    add_progress(parser)
    add_limit_options(parser, ("frames",))
    return parser


def config_from_args(args: argparse.Namespace) -> SimulationConfig:
    cloth = ClothParams(iterations=args.iterations, membrane_weight=args.membrane_weight,
                        bending_weight=args.bending_weight, density=args.density,
                        contact_weight=args.contact_weight, contact_radius=args.contact_radius,
                        contact_cg_iterations=args.contact_cg_iterations)
    betas = None
    if args.betas:
        try:
            betas = tuple(float(v) for v in args.betas.split(","))
        except ValueError as exc:
            raise ValueError(f"--betas must be comma-separated numbers, got {args.betas!r}") from exc
    return SimulationConfig(
        garment=args.garment, motion=args.motion, body=args.body, frames=args.frames, betas=betas, seed=args.seed,
        transition_seconds=args.transition_seconds, motion_speed=args.speed, cloth=cloth,
        dressing=DressingParams(level_mm=args.level, pose=args.pose, cloth=cloth),
        health=HealthLimits(args.max_penetration_mm * 1e-3, args.max_strain),
    )


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def action() -> None:
        limits_from_args(args).check("frames", args.frames, "the number of frames", "--frames")
        out = Path(args.out)
        sequence = simulate(config_from_args(args), out, progress=progress(args))
        if not args.no_preview:
            write_preview(sequence, out / "preview.png")
        print(sequence)

    return run_cli(action, failures=(SimulationError,))


if __name__ == "__main__":
    sys.exit(main())
