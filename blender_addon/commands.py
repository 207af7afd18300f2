"""The scene's settings -> the project's command lines and the folders they write.

Every long step of the add-on is one of the project's CLIs, given exactly the arguments a person would
type, and the progress bars it shows (`jobs.Job.stages`); nothing here computes anything else.
Folders, below the output folder ``<output>``:

  pattern/                       python -m assets.pattern
  garments/<garment>/            python -m assets.garments build (template.npz, pattern_texture.png)
  motions/<motion>/              python -m assets.motion preview (body_sequence.npz, motion.npz)
  simulations/<garment>-<motion>/  python -m factory.simulate (dressed.npz, sequence.npz)
  dataset/ or capture/           python -m factory.dataset build | capture (or the Render panel's folder)
  reconstruction/                python -m reconstruction run (or the Review panel's folder)

The garment given to the simulation and the factory is the template built by the Garment panel when
there is one (its pitch, seed and texture follow the Pattern panel), else the default garment or the
pattern file itself; the simulation folder is handed to the factory (``--reuse-simulation``) with the
options it was made with (simulation level, motion speed, the Render panel's seed), so that it is the
same simulation (the factory refuses one made with other options, naming them: a seed changed since
the simulation, for one).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import bpy

from . import library
from .settings import FILE, UNAVAILABLE


def blend_folder() -> Path:
    """What ``//`` stands for: the .blend file's folder, or for an unsaved file Blender's temporary
    folder (Preferences > File Paths > Temporary Files, else the system's), so that the default output
    folder works before the file is first saved."""
    if bpy.data.filepath:
        return Path(bpy.data.filepath).parent
    return Path(bpy.context.preferences.filepaths.temporary_directory or tempfile.gettempdir())


def _path(text: str, what: str) -> Path:
    """An absolute path from a setting (``//``: `blend_folder`); ValueError when empty or relative."""
    if not text:
        raise ValueError(f"{what}: no path given")
    path = blend_folder() / text[2:] if text.startswith("//") else Path(bpy.path.abspath(text))
    if not path.is_absolute():
        raise ValueError(f"{what}: '{text}' is a relative path: give an absolute folder or one starting with //")
    return path


def _existing_file(text: str, what: str) -> Path:
    path = _path(text, what)
    if not path.is_file():
        raise ValueError(f"{what}: {path} does not exist")
    return path


def output_root(settings) -> Path:
    return _path(settings.output_dir, "output folder")


def _number(value: float) -> str:
    return f"{value:.6g}"


#: the progress bars of each CLI, in order (the beginnings of their descriptions)
PATTERN_STAGES = ("render",)
GARMENT_STAGES = ("sheet",)
SIMULATION_STAGES = ("sewing", "simulating")
RECONSTRUCTION_STAGES = ("detect", "triangulate", "refine pass 1", "refine pass 2", "export obj", "export ply")


# ---- pattern ---------------------------------------------------------------------------------------
def pattern_dir(settings) -> Path:
    return output_root(settings) / "pattern"


def pattern_spec_args(pattern) -> list[str]:
    return ["--pitch-mm", _number(pattern.pitch_mm), "--seed", str(pattern.seed)]


def pattern_command(settings) -> tuple[list[str], Path]:
    p, out = settings.pattern, pattern_dir(settings)
    return (["-m", "assets.pattern", "--out", str(out), *pattern_spec_args(p), "--rows", str(p.rows),
             "--cols", str(p.cols), "--dpi", _number(p.dpi)], out)


# ---- body and motion -------------------------------------------------------------------------------
def body_spec(settings) -> str:
    m = settings.motion
    return str(_existing_file(m.body_file, "body file")) if m.body_source == FILE else "default"


def _listed(value: str, module: str) -> str:
    """A choice from a list the project fills (in `module`); ValueError saying why the list is empty."""
    if value == UNAVAILABLE:
        library.project_module(module)  # raises what keeps Blender from loading the project
        raise ValueError("no choice made: pick one from the list again")
    return value


def motion_spec(settings) -> str:
    m = settings.motion
    return str(_existing_file(m.file, "motion file")) if m.source == FILE else \
        _listed(m.builtin, "assets.motion.builtin")


def motion_name(settings) -> str:
    """The motion's name, which names its folders (``motions/<motion>``): its `motion_label`, one plain
    path component."""
    m = settings.motion
    spec = bpy.path.abspath(m.file) if m.source == FILE else _listed(m.builtin, "assets.motion.builtin")
    return library.project_module("assets.motion.sources").motion_label(spec)


def motion_command(settings) -> tuple[list[str], Path]:
    m = settings.motion
    out = output_root(settings) / "motions" / motion_name(settings)
    argv = ["-m", "assets.motion", "preview", motion_spec(settings), "--body", body_spec(settings), "--out", str(out),
            "--speed", _number(m.speed), "--fps", _number(m.fps), "--transition", m.transition, "--frames", "4"]
    return argv + (["--seconds", _number(m.seconds)] if m.seconds > 0 else []), out


# ---- garment ---------------------------------------------------------------------------------------
def garment_name(settings) -> str:
    """The garment's name, which names its folders (``garments/<garment>``): one plain path component."""
    g = settings.garment
    if g.source != FILE:
        return _listed(g.source, "assets.garments.defaults")
    path = Path(bpy.path.abspath(g.file))
    return library.project_module("assets.fileio").safe_name(
        path.parent.name if path.name == "template.npz" else path.stem, "garment file")


def garment_source(settings) -> str:
    """What `assets.garments.load_template` takes: a default garment's name or the file."""
    g = settings.garment
    return str(_existing_file(g.file, "garment file")) if g.source == FILE else \
        _listed(g.source, "assets.garments.defaults")


def garment_dir(settings) -> Path:
    return output_root(settings) / "garments" / garment_name(settings)


def garment_command(settings, source: str | None = None, out: Path | None = None,
                    level_mm: int | None = None) -> tuple[list[str], Path]:
    """Build a template: the Garment panel's garment, or `source` into `out` at `level_mm` (a garment
    re-textured from the Pattern panel); its pitch and seed are the Pattern panel's."""
    g = settings.garment
    out = out or garment_dir(settings)
    level = level_mm or int(g.level_mm)
    return (["-m", "assets.garments", "build", source or garment_source(settings), "--out", str(out),
             "--levels", str(level), "--dpi", _number(g.texture_dpi), *pattern_spec_args(settings.pattern),
             "--formats", "obj"], out)


def garment_spec(settings) -> str:
    """The garment of the simulation and the factory: the Garment panel's built template if any."""
    built = garment_dir(settings) / "template.npz"
    return str(built) if built.is_file() else garment_source(settings)


def simulation_dir(settings) -> Path:
    return output_root(settings) / "simulations" / f"{garment_name(settings)}-{motion_name(settings)}"


def simulation_command(settings) -> tuple[list[str], Path]:
    g, m = settings.garment, settings.motion
    out = simulation_dir(settings)
    # the Render panel's seed: the factory's simulation records its seed, and reuses only an identical one
    argv = ["-m", "factory.simulate", "--garment", garment_spec(settings), "--motion", motion_spec(settings),
            "--body", body_spec(settings), "--frames", str(g.sim_frames), "--level", g.sim_level_mm,
            "--seed", str(settings.render.seed), "--out", str(out), "--no-preview"]
    return argv + (["--speed", _number(m.speed)] if m.speed != 1.0 else []), out


# ---- render ----------------------------------------------------------------------------------------
def render_dir(settings, rig: str | None = None) -> Path:
    r = settings.render
    if r.output_dir and (rig is None or rig == r.rig):
        return _path(r.output_dir, "render output folder")
    return output_root(settings) / ("capture" if (rig or r.rig) == "CAPTURE" else "dataset")


def render_command(settings) -> tuple[list[str], Path]:
    r = settings.render
    out = render_dir(settings)
    motion = motion_spec(settings)
    common = ["--garment", garment_spec(settings), "--body", body_spec(settings), "--seed", str(r.seed),
              "--level", settings.garment.sim_level_mm, "--speed", _number(settings.motion.speed),
              "--resolution", f"{r.width}x{r.height}", "--engine", r.engine, "--samples", str(r.samples),
              "--texture-dpi", _number(r.texture_dpi), *([] if r.denoise else ["--no-denoise"]), "--out", str(out)]
    simulation = simulation_dir(settings)
    reuse = (simulation / "sequence.npz").is_file()
    if r.rig == "CAPTURE":
        argv = ["-m", "factory.dataset", "capture", "--motion", motion, "--frames", str(r.frames), "--cameras",
                str(r.cameras), "--radius", _number(r.radius), "--height", _number(r.ring_height)]
        argv += ["--first-frame", str(r.first_frame)] if r.first_frame >= 0 else []
        argv += ["--reuse-simulation", str(simulation)] if reuse else []
    else:
        argv = ["-m", "factory.dataset", "build", "--motions", motion, "--frames", str(r.frames), "--frame-step",
                str(r.frame_step), "--variations", str(r.variations)]
        argv += ["--frame-list", r.frame_list.replace(" ", "")] if r.frame_list.strip() else []
        argv += ["--reuse-simulation", f"{motion}={simulation}"] if reuse else []
    return argv + common, out


def render_stages(settings) -> tuple[str, ...]:
    """A capture: the garment's texture, the simulation (unless reused), then each camera's images and
    ground truth; a dataset: one bar over its tasks."""
    r = settings.render
    if r.rig != "CAPTURE":
        return ("dataset",)
    return ("sheet",) + SIMULATION_STAGES + ("render", "ground truth") * r.cameras


# ---- reconstruction --------------------------------------------------------------------------------
def capture_dir(settings) -> Path:
    review = settings.review
    return _path(review.capture_dir, "capture folder") if review.capture_dir else render_dir(settings, "CAPTURE")


def reconstruction_dir(settings) -> Path:
    review = settings.review
    if review.reconstruction_dir:
        return _path(review.reconstruction_dir, "reconstruction folder")
    return output_root(settings) / "reconstruction"


def reconstruction_command(settings) -> tuple[list[str], Path]:
    review = settings.review
    capture, out = capture_dir(settings), reconstruction_dir(settings)
    if not (capture / "cameras.json").is_file():
        raise ValueError(f"{capture}: not a capture folder (no cameras.json): render a capture first")
    argv = ["-m", "reconstruction", "run", "--views", str(capture), "--template", str(capture / "template.npz"),
            "--out", str(out), "--detections", review.detections]
    if review.detections == "groundtruth":
        argv += ["--noise", _number(review.noise_px), "--dropout", _number(review.dropout), "--evaluate"]
    else:
        argv += ["--cameras", str(capture / "cameras.json")]
        argv += [arg for name in ("localizer", "recognizer", "crosspoints")
                 for arg in (f"--{name}", str(_existing_file(getattr(review, name), f"{name} checkpoint")))]
    argv += [] if review.neighbour_check else ["--no-neighbour-check"]
    return argv + (["--levels", review.levels.replace(" ", "")] if review.levels.strip() else []), out
