"""Physics-based post-processing: captured points of every frame -> a complete, intersection-free
garment sequence on the template's finest chosen level (the reference's Newton VBD pass).

    sequence = refine_sequence(template, captures, RefineConfig(levels_mm=(12, 4)), out="out/refine")
    sequence.save("out/refined.npz")

Per frame and level (coarse to fine, `reconstruction.hierarchy`):
1. anchoring (`reconstruction.anchors`): the level's captured vertices and their anchor targets;
2. rest shape (`reconstruction.restshape`): observed where a stencil is captured, else the previous
   frame's solved shape, else the template's;
3. start: the coarsest level starts from the neighbouring frame's solution, each finer level from the
   coarser solution upsampled barycentrically; a start that intersects itself is refilled around the
   intersections first (`reconstruction.intersections.untangle`);
4. solve (`reconstruction.vbd`): anchors (1e6), stable Neo-Hookean membrane (mu 1e2, lambda 1e1),
   dihedral bending (1e-1), barrier self-contact (1e4, radius 1 mm), quasi-static VBD steps.

The first frame solved, t_i (`start_frame`; by default the frame with the most captured vertices on
the coarsest level), starts from the penetration-free template: `initial_shape` (for example the
factory's dressed garment), else the template's placement-hint pose, moved by a rigid fit (Kabsch) to
the captured points of t_i, then deformed progressively by anchor weights ramping up to the full
weight (`initial_weights`).  Pass 1 propagates forwards from t_i to the last frame, then backwards
from t_i to the first, each frame starting from its neighbour's solution.  Pass 2 (`smoothing_pass`)
solves the finest level of every frame again from its pass-1 solution with the bidirectionally
smoothed rest shape (stencils not captured take the mean of the previous and next frames' shapes).

With `out`, every finished frame of each pass is written there (``pass1/f<frame>.npz`` with every
level's shape, ``final/f<frame>.npz``) and a rerun with the same captures and config skips it: what the
run is made of (the config, frames, start frame, template, digests of the captures and the initial
shape) is recorded in ``refine_run.json`` (`assets.fileio.record_stage`; the config's fields by their
names), and a rerun with any of it changed is refused, naming what differs.

Diagnostics per frame (finest level, lengths in mm): captured_vertices (surrounded by captured points,
`reconstruction.anchors`), anchored_vertices (those less the vertices of faces where the capture
itself intersects: their targets would pull the cloth through itself), points, fit_rms_mm,
anchor_rms_mm, anchor_max_mm (solved anchored vertices from their targets), intersections_before (the
start with its captured vertices moved onto their targets: what the capture gives without the
physics), intersections_start (the shape the solve started from), untangle_left (pairs the refill
could not remove), repair_solves, intersections_after, seconds; "levels": the same per level, keyed
by mm; "pass1": pass 1's diagnostics, when pass 2 ran.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Sequence

import numpy as np

from assets.fileio import load_json, load_npz, record_stage, save_json, save_npz
from assets.garments.template import Template
from reconstruction.anchors import Anchors, LevelAnchoring, rigid_fit
from reconstruction.hierarchy import Hierarchy
from reconstruction.intersections import count_intersections, intersecting_pairs, untangle
from reconstruction.points import CapturedPoints
from reconstruction.restshape import RestShape, dynamic_rest, measure, pattern_rest, smoothed_rest, stencils_captured

log = logging.getLogger(__name__)

_THIN_FRACTION = 1e-3  # triangles thinner than the contact radius that still allow contact between neighbours
_QUERY_FRACTION = 0.9  # self-contact query radius / (1st-percentile triangle altitude x filter rings)
_MIN_GAP_FRACTION = 0.25  # smallest contact gap, in contact radii


@dataclass(frozen=True)
class RefineConfig:
    """The post-processing's numbers; the energy weights are the reference's (see `reconstruction.vbd`)."""

    levels_mm: tuple[int, ...] = (12, 4, 2, 1)  #: template levels, solved coarse to fine
    anchor_weight: float = 1.0e6  #: N/m, zero-rest-length spring per captured vertex
    membrane_mu: float = 1.0e2  #: N/m, Lame mu of Newton's stable Neo-Hookean membrane (reference: StVK)
    membrane_lambda: float = 1.0e1  #: N/m, Lame lambda
    bending_weight: float = 1.0e-1  #: N m, dihedral bending (Newton's edge_ke)
    contact_weight: float = 1.0e4  #: N/m, barrier self-contact stiffness
    contact_radius: float = 1.0e-3  #: m, self-contact interaction distance
    #: m, extra self-contact detection distance (at most; less on levels whose triangles are thinner,
    #: see `_Refiner.solver`); one VBD step moves a vertex at most 0.425 (contact_radius + gap)
    contact_gap: float = 4.0e-3
    density_g_m2: float = 100.0  #: lumped masses for VBD's inertia term (quasi-static: it only damps)
    timestep: float = 1.0 / 30.0  #: s, pseudo-time step of one quasi-static VBD step
    iterations: int = 5  #: VBD iterations per step
    steps: int = 20  #: VBD steps per frame on the coarsest level
    fine_steps: int = 4  #: VBD steps per frame on each finer level (it starts from the coarser solution)
    initial_weights: tuple[float, ...] = (1.0e2, 1.0e3, 1.0e4, 1.0e5, 1.0e6)  #: N/m, ramp at t_i
    initial_steps: int = 40  #: VBD steps per ramp stage at t_i (coarsest level)
    capture_radius: float = 1.0  #: neighbourhood radius for "captured", in max(level spacing, 2 pitches)
    capture_coverage: float = 0.5  #: fraction of the neighbourhood's crosspoints that must be captured
    capture_sectors: int = 4  #: angular sectors that must each hold a captured crosspoint
    fit_regularizer: float = 1.0e-2  #: Laplacian weight of the anchor-target fit, per crosspoint
    untangle_rings: int = 2  #: rings grown per round around intersections refilled before a solve
    untangle_rounds: int = 4
    #: rounds of untangling and `steps` more VBD steps when a solve ends with intersections (Newton's
    #: contact bounds are conservative, but we measured a few crossings under the stiff anchors)
    repair_solves: int = 2
    smoothing_pass: bool = True  #: pass 2: bidirectional rest-shape smoothing

    def __post_init__(self) -> None:
        object.__setattr__(self, "levels_mm", tuple(int(mm) for mm in self.levels_mm))
        object.__setattr__(self, "initial_weights", tuple(float(w) for w in self.initial_weights))
        positive = ("anchor_weight", "membrane_mu", "contact_weight", "contact_radius", "density_g_m2", "timestep",
                    "iterations", "steps", "fine_steps", "initial_steps", "capture_radius", "capture_sectors")
        bad = [name for name in positive if not getattr(self, name) > 0]
        bad += [name for name in ("membrane_lambda", "bending_weight", "contact_gap", "fit_regularizer",
                                  "untangle_rings", "untangle_rounds", "repair_solves") if not getattr(self, name) >= 0]
        if not self.levels_mm or min(self.levels_mm) <= 0 or len(set(self.levels_mm)) != len(self.levels_mm):
            bad.append("levels_mm")
        if not 0 < self.capture_coverage <= 1:
            bad.append("capture_coverage")
        if not self.initial_weights or min(self.initial_weights) <= 0:
            bad.append("initial_weights")
        if bad:
            raise ValueError(f"RefineConfig: invalid {', '.join(bad)} ({self})")

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict, source: str = "config") -> "RefineConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known) if isinstance(data, dict) else []
        if not isinstance(data, dict) or unknown:
            raise ValueError(f"{source}: expected an object with keys from {sorted(known)}, unknown: {unknown}")
        return cls(**data)

    def save(self, path: str | Path) -> None:
        save_json(path, self.to_dict())

    @classmethod
    def load(cls, path: str | Path) -> "RefineConfig":
        return cls.from_dict(load_json(path), str(path))


@dataclass(frozen=True, eq=False)
class RefinedSequence:
    """The post-processed sequence on one template level (T frames, V sewn vertices, F faces).

    level_mm int                 the template level (finest of the hierarchy)
    positions (T, V, 3) float32  complete vertex positions, world metres
    captured (T, V) bool         vertices anchored to captured points (`anchored_vertices`)
    faces (F, 3) int32           the level's sewn faces
    frames (T,) int64            frame numbers (the captures')
    start_frame int              index t_i of the frame solved first
    source str                   where the 2D observations came from (the captures' source)
    diagnostics list[dict]       per frame (see the module docstring)
    config dict                  the RefineConfig used
    """

    level_mm: int
    positions: np.ndarray
    captured: np.ndarray
    faces: np.ndarray
    frames: np.ndarray
    start_frame: int
    source: str
    diagnostics: list
    config: dict

    def __len__(self) -> int:
        return len(self.positions)

    def save(self, path: str | Path) -> None:
        save_npz(path, {
            "level_mm": np.int64(self.level_mm), "positions": self.positions, "captured": self.captured,
            "faces": self.faces, "frames": self.frames, "start_frame": np.int64(self.start_frame),
            "source": np.array(self.source), "diagnostics_json": np.array(json.dumps(self.diagnostics)),
            "config_json": np.array(json.dumps(self.config)),
        })

    @classmethod
    def load(cls, path: str | Path) -> "RefinedSequence":
        keys = ("level_mm", "positions", "captured", "faces", "frames", "start_frame", "source", "diagnostics_json",
                "config_json")
        data = load_npz(path, required=keys)
        positions, captured = data["positions"], data["captured"]
        if positions.ndim != 3 or positions.shape[2] != 3 or captured.shape != positions.shape[:2]:
            raise ValueError(f"{path}: positions (T, V, 3) and captured (T, V) expected, got {positions.shape} and "
                             f"{captured.shape}")
        return cls(int(data["level_mm"]), positions, captured, data["faces"], data["frames"], int(data["start_frame"]),
                   str(data["source"]), json.loads(str(data["diagnostics_json"])), json.loads(str(data["config_json"])))


def refine_sequence(template: Template, captures: Sequence[CapturedPoints], config: RefineConfig = RefineConfig(),
                    start_frame: int | None = None, progress: bool = True, out: str | Path | None = None,
                    initial_shape: np.ndarray | None = None, initial_level_mm: int | None = None,
                    device: str = "cpu") -> RefinedSequence:
    """Post-process a captured sequence (see the module docstring).

    captures: one CapturedPoints per frame, in time order (their keys are what is used).
    start_frame: index of t_i in `captures`, or None for the frame with the most captured vertices.
    out: folder for per-frame results (resume); None keeps everything in memory.
    initial_shape: (V, 3) a penetration-free shape of the sewn mesh of level `initial_level_mm`
        (default: the coarsest level), e.g. `load_initial_shape(dressed.npz)`; None: the template's
        placement-hint pose (`assets.garments.export.placed_positions`), flat panels with seams
        stretched across the body: far from penetration-free (3379 intersecting pairs once fitted to a
        walking shirt's capture) and a poor start (anchors then end 64 mm RMS from their targets, where
        the dressed garment gives 0.2 mm): pass a dressed shape.
    device: where Newton's VBD solves run ("cpu", "cuda", "cuda:1"); the same energies and float32
        solves either way, so it is not part of what `out` records."""
    return _Refiner(template, captures, config, out, progress, device).run(start_frame, initial_shape,
                                                                           initial_level_mm)


def load_initial_shape(path: str | Path) -> tuple[np.ndarray, int]:
    """A garment shape npz with ``positions`` (V, 3) and ``meta`` JSON holding ``level_mm`` (the
    factory's dressed garment, ``sim/<motion>/dressed.npz``) -> (positions, level_mm)."""
    data = load_npz(path, required=("positions", "meta"))
    try:
        level_mm = int(json.loads(str(data["meta"]))["level_mm"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: meta must be JSON with an integer level_mm ({exc})") from exc
    positions = np.asarray(data["positions"], dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"{path}: positions must be (V, 3), got {positions.shape}")
    return positions, level_mm


class _Refiner:
    """The state of one refine_sequence call: per-level anchoring, solvers and template rest shapes."""

    def __init__(self, template: Template, captures: Sequence[CapturedPoints], config: RefineConfig,
                 out: str | Path | None, progress: bool, device: str = "cpu"):
        if not captures:
            raise ValueError("captures: expected at least one frame of CapturedPoints")
        sources = sorted({points.source for points in captures})
        if len(sources) > 1:
            raise ValueError(f"captures: frames come from different sources {sources}")
        self.template, self.captures, self.config = template, list(captures), config
        self.hierarchy = Hierarchy(template, config.levels_mm)
        self.frames = np.array([p.frame if p.frame >= 0 else i for i, p in enumerate(captures)], dtype=np.int64)
        if len(set(self.frames.tolist())) != len(self.frames):
            raise ValueError(f"captures: frame numbers must be distinct, got {self.frames.tolist()}")
        self.source = sources[0]
        self.out = None if out is None else Path(out)
        self.reuse = False  # whether the frames in `out` are this run's (`_record`)
        self.progress = progress
        self.device = device
        self._anchoring: dict[int, LevelAnchoring] = {}
        self._solvers: dict[int, object] = {}
        self._template_rest: dict[int, RestShape] = {}

    # ---- per-level resources -------------------------------------------------------------------
    def anchoring(self, mm: int) -> LevelAnchoring:
        if mm not in self._anchoring:
            c = self.config
            self._anchoring[mm] = LevelAnchoring(self.template, mm, c.capture_radius, c.capture_coverage,
                                                 c.capture_sectors, c.fit_regularizer)
        return self._anchoring[mm]

    def solver(self, mm: int, positions: np.ndarray):
        """The level's Newton cloth, built on first use from `positions` (then only its topology,
        masses and rest shapes matter)."""
        if mm not in self._solvers:
            from reconstruction.vbd import ClothSolver

            c, level = self.config, self.hierarchy.level(mm)
            corners = level.pattern_xy[level.faces]
            area = 0.5 * np.abs(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
            mass = np.bincount(level.sewn_faces.ravel(), np.repeat(area / 3.0, 3), minlength=len(positions))
            mass *= c.density_g_m2 * 1e-3
            faces = level.sewn_faces
            # Self-contact between topological neighbours too (so that a fold at a seam is caught)
            # where they cannot touch at rest: at most 0.1 % of the pattern triangles have an altitude
            # under the contact radius (the 12, 4 and 2 mm levels; those few get a small spurious
            # push).  The gap keeps the query under 0.9 of the 1st-percentile altitude (neighbours in
            # the query cost time even without force).  Elsewhere Newton's default, pairs within two
            # rings ignored, with the query under 0.9 of twice that altitude.  Gap at least a quarter
            # of the contact radius, at most `contact_gap`.
            altitude = 2.0 * area / np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2).max(axis=1)
            rings = 1 if np.mean(altitude < c.contact_radius) <= _THIN_FRACTION else 2
            reach = _QUERY_FRACTION * rings * float(np.percentile(altitude, 1.0))
            gap = min(c.contact_gap, max(reach - c.contact_radius, _MIN_GAP_FRACTION * c.contact_radius))
            log.info("refine %d mm: self-contact query %.2f mm, topological filter %d ring(s)", mm,
                     (c.contact_radius + gap) * 1e3, rings)
            solver = ClothSolver(
                faces, positions, mass, anchor_weight=c.anchor_weight, membrane_mu=c.membrane_mu,
                membrane_lambda=c.membrane_lambda, bending_weight=c.bending_weight, contact_weight=c.contact_weight,
                contact_radius=c.contact_radius, contact_gap=gap, timestep=c.timestep,
                iterations=c.iterations, contact_filter_rings=rings, device=self.device)
            self._template_rest[mm] = pattern_rest(level.pattern_xy, level.faces, faces, solver.hinges)
            solver.set_rest(self._template_rest[mm])
            self._solvers[mm] = solver
        return self._solvers[mm]

    # ---- the two passes ------------------------------------------------------------------------
    def run(self, start_frame: int | None, initial_shape: np.ndarray | None,
            initial_level_mm: int | None) -> RefinedSequence:
        count, coarsest, finest = len(self.captures), self.hierarchy.coarsest_mm, self.hierarchy.finest_mm
        if start_frame is None:
            captured = [int(self.anchoring(coarsest).captured_vertices(p.key).sum()) for p in self.captures]
            start_frame = int(np.argmax(captured))
        if not 0 <= int(start_frame) < count:
            raise ValueError(f"start_frame: expected an index in [0, {count}), got {start_frame}")
        start_frame = int(start_frame)
        self._record(start_frame, initial_shape, initial_level_mm)
        level = self.hierarchy.level(finest)
        positions = np.zeros((count, level.num_sewn_vertices, 3), np.float32)
        captured = np.zeros((count, level.num_sewn_vertices), bool)
        diagnostics: list[dict] = [{} for _ in range(count)]

        order = [(start_frame, None)] + [(t, t - 1) for t in range(start_frame + 1, count)]
        order += [(t, t + 1) for t in range(start_frame - 1, -1, -1)]
        solved: dict[int, dict[int, np.ndarray]] = {}  # frame -> level -> shape, only those still needed
        from tqdm import tqdm  # here, not at import: Blender's own Python may lack it
        for t, neighbour in tqdm(order, desc="refine pass 1", unit="frame", disable=not self.progress):
            path = self._path("pass1", t)
            if self.reuse and path.exists():
                shapes, captured[t], diagnostics[t] = self._read(path)
            else:
                if neighbour is None:
                    start, previous = self._initial(t, initial_shape, initial_level_mm), None
                else:
                    start, previous = solved[neighbour][coarsest], solved[neighbour]
                shapes, captured[t], diagnostics[t] = self._solve_frame(t, start, previous, initial=neighbour is None)
                if path is not None:
                    self._write(path, shapes, captured[t], diagnostics[t])
            solved[t] = shapes
            positions[t] = shapes[finest]
            if neighbour is not None and neighbour != start_frame:
                del solved[neighbour]

        if self.config.smoothing_pass and count > 1:
            first = positions.copy()
            from tqdm import tqdm
            for t in tqdm(range(count), desc="refine pass 2", unit="frame", disable=not self.progress):
                path = self._path("final", t)
                if self.reuse and path.exists():
                    shapes, captured[t], diagnostics[t] = self._read(path)
                else:
                    shapes, captured[t], diagnostics[t] = self._smooth_frame(t, first, diagnostics[t])
                    if path is not None:
                        self._write(path, shapes, captured[t], diagnostics[t])
                positions[t] = shapes[finest]
        return RefinedSequence(finest, positions, captured, level.sewn_faces.astype(np.int32), self.frames,
                               start_frame, self.source, diagnostics, self.config.to_dict())

    def _initial(self, t: int, shape: np.ndarray | None, level_mm: int | None) -> np.ndarray:
        """The penetration-free template on the coarsest level, rigidly fitted to frame t's points."""
        coarsest = self.hierarchy.coarsest_mm
        if shape is None:
            from assets.garments.export import placed_positions

            shape, level_mm = self.hierarchy.level(coarsest).sew(placed_positions(self.template, coarsest)), coarsest
        x = self.hierarchy.transfer(shape, coarsest if level_mm is None else int(level_mm), coarsest)
        points = self.captures[t]
        on_shape = self.anchoring(coarsest).points_on(x, points.key)
        usable = np.isfinite(on_shape).all(axis=1) & (points.confidence > 0)
        if usable.sum() < 3:
            raise ValueError(f"captures[{t}] (frame {self.frames[t]}): {int(usable.sum())} captured points on the "
                             "fabric, at least 3 needed to place the template")
        rotation, translation = rigid_fit(on_shape[usable], points.xyz[usable], points.confidence[usable])
        return x @ rotation.T + translation

    # ---- one frame -----------------------------------------------------------------------------
    def _solve_frame(self, t: int, start: np.ndarray, previous: dict[int, np.ndarray] | None,
                     initial: bool) -> tuple[dict[int, np.ndarray], np.ndarray, dict]:
        """Pass 1 for frame t: every level, coarse to fine (module docstring)."""
        c, points = self.config, self.captures[t]
        shapes: dict[int, np.ndarray] = {}
        levels: dict[str, dict] = {}
        x = np.asarray(start, dtype=np.float64)
        for i, mm in enumerate(self.hierarchy.levels_mm):
            if i:
                x = self.hierarchy.transfer(x, self.hierarchy.levels_mm[i - 1], mm)
            anchors = self.anchoring(mm).anchors(points.key, points.xyz, points.confidence, reference=x)
            anchored, conflicts = self._anchored(mm, anchors, x)
            solver = self.solver(mm, x)
            faces = self.hierarchy.level(mm).sewn_faces
            snapped = np.where(anchored[:, None], anchors.targets, x)
            prior = None if previous is None else measure(previous[mm].astype(np.float64), faces, solver.hinges)
            rest = dynamic_rest(measure(snapped, faces, solver.hinges),
                                *stencils_captured(anchored, faces, solver.hinges), prior, self._template_rest[mm])
            ramp = c.initial_weights if initial and i == 0 else (c.anchor_weight,)
            steps = (c.initial_steps if initial else c.steps) if i == 0 else c.fine_steps
            x, levels[str(mm)] = self._solve_level(mm, x, anchors, anchored, conflicts, rest, ramp, steps)
            shapes[mm] = x.astype(np.float32)
        return shapes, anchored, {**levels[str(mm)], "levels": levels}

    def _smooth_frame(self, t: int, first: np.ndarray, pass1: dict) -> tuple[dict[int, np.ndarray], np.ndarray, dict]:
        """Pass 2 for frame t: the finest level again from its pass-1 shape with the smoothed rest."""
        mm, points = self.hierarchy.finest_mm, self.captures[t]
        x = first[t].astype(np.float64)
        anchors = self.anchoring(mm).anchors(points.key, points.xyz, points.confidence, reference=x)
        anchored, _ = self._anchored(mm, anchors, x)
        solver = self.solver(mm, x)
        faces = self.hierarchy.level(mm).sewn_faces
        snapped = np.where(anchored[:, None], anchors.targets, x)
        sides = [measure(first[s].astype(np.float64), faces, solver.hinges) if 0 <= s < len(first) else None
                 for s in (t - 1, t + 1)]
        rest = smoothed_rest(measure(snapped, faces, solver.hinges), *stencils_captured(anchored, faces, solver.hinges),
                             *sides, self._template_rest[mm])
        steps = self.config.steps if len(self.hierarchy.levels_mm) == 1 else self.config.fine_steps
        # "before" stays what the capture gave before any physics (with pass 1's fill)
        x, info = self._solve_level(mm, x, anchors, anchored, pass1["intersections_before"], rest,
                                    (self.config.anchor_weight,), steps)
        return {mm: x.astype(np.float32)}, anchored, {**info, "pass1": pass1}

    def _anchored(self, mm: int, anchors: Anchors, start: np.ndarray) -> tuple[np.ndarray, int]:
        """The captured vertices that get anchor springs, and the number of intersecting pairs of the
        capture itself (captured vertices on their targets, the rest at `start`).  A face of such a pair
        releases its vertices: their targets would pull the cloth through itself, and the contact
        barrier would fight the 1e6 springs (noise, or a capture of cloth that touches itself)."""
        faces = self.hierarchy.level(mm).sewn_faces
        conflicts = intersecting_pairs(np.where(anchors.captured[:, None], anchors.targets, start), faces)
        anchored = anchors.captured.copy()
        anchored[faces[conflicts].ravel()] = False
        return anchored, len(conflicts)

    def _solve_level(self, mm: int, start: np.ndarray, anchors: Anchors, anchored: np.ndarray, conflicts: int,
                     rest: RestShape, weights: Sequence[float], steps: int) -> tuple[np.ndarray, dict]:
        """Untangle the start if needed, then VBD steps per anchor weight (and, should intersections
        remain, up to `repair_solves` rounds of untangling and `steps` more); returns the shape and
        its diagnostics (lengths in mm)."""
        began = time.perf_counter()
        c = self.config
        faces = self.hierarchy.level(mm).sewn_faces
        targets = anchors.targets
        at_start = count_intersections(start, faces)
        left = 0
        x = start
        if at_start:
            x, left = untangle(start, faces, anchored, c.untangle_rings, c.untangle_rounds)
        solver = self.solver(mm, x)
        solver.set_rest(rest)
        for weight in weights:
            x = solver.solve(x, targets, anchored, steps, anchor_weight=weight)
        after, repairs = count_intersections(x, faces), 0
        while after and repairs < c.repair_solves:
            x, _ = untangle(x, faces, anchored, c.untangle_rings, c.untangle_rounds)
            x = solver.solve(x, targets, anchored, steps)
            after, repairs = count_intersections(x, faces), repairs + 1
        residual = np.linalg.norm(x[anchored] - targets[anchored], axis=1) if anchored.any() else np.zeros(1)
        info = {
            "captured_vertices": int(anchors.captured.sum()), "anchored_vertices": int(anchored.sum()),
            "points": anchors.points, "fit_rms_mm": anchors.fit_rms * 1e3,
            "anchor_rms_mm": float(np.sqrt(np.mean(residual**2)) * 1e3), "anchor_max_mm": float(residual.max() * 1e3),
            "intersections_before": int(conflicts), "intersections_start": int(at_start), "untangle_left": int(left),
            "repair_solves": repairs, "intersections_after": int(after), "seconds": time.perf_counter() - began,
        }
        log.info("refine %d mm: %d captured, %d anchored, anchors rms %.3f max %.3f mm, intersections %d -> %d "
                 "(%d repairs), %.1f s", mm, info["captured_vertices"], info["anchored_vertices"], info["anchor_rms_mm"],
                 info["anchor_max_mm"], at_start, after, repairs, info["seconds"])
        return x, info

    # ---- files ---------------------------------------------------------------------------------
    def _path(self, stage: str, t: int) -> Path | None:
        return None if self.out is None else self.out / stage / f"f{int(self.frames[t]):06d}.npz"

    def _record(self, start_frame: int, initial_shape: np.ndarray | None, initial_level_mm: int | None) -> None:
        """Record what this run is in ``out/refine_run.json``; a folder another run made is refused,
        naming what differs.  Frames in a folder without the record (an older version's) are solved
        again."""
        if self.out is None:
            return
        captures = hashlib.sha1()
        for points in self.captures:
            for array in (points.key, points.xyz, points.confidence):
                captures.update(np.ascontiguousarray(array).tobytes())
        initial = "placement hints" if initial_shape is None else hashlib.sha1(
            np.ascontiguousarray(initial_shape, dtype=np.float64).tobytes()).hexdigest()
        run = {**self.config.to_dict(), "frames": self.frames.tolist(), "start_frame": start_frame,
               "captures": captures.hexdigest(), "source": self.source, "template": self.template.name,
               "initial_shape": initial, "initial_level_mm": initial_level_mm}
        self.out.mkdir(parents=True, exist_ok=True)
        self.reuse = record_stage(self.out / "refine_run.json", run)

    def _write(self, path: Path, shapes: dict[int, np.ndarray], captured: np.ndarray, diagnostics: dict) -> None:
        save_npz(path, {**{f"L{mm}": shape for mm, shape in shapes.items()}, "captured": captured,
                        "diagnostics_json": np.array(json.dumps(diagnostics))})

    def _read(self, path: Path) -> tuple[dict[int, np.ndarray], np.ndarray, dict]:
        data = load_npz(path, required=("captured", "diagnostics_json"))
        shapes = {int(key[1:]): value for key, value in data.items() if key.startswith("L")}
        if self.hierarchy.finest_mm not in shapes:
            raise ValueError(f"{path}: missing the {self.hierarchy.finest_mm} mm shape (L{self.hierarchy.finest_mm})")
        return shapes, data["captured"], json.loads(str(data["diagnostics_json"]))
