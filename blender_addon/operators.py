"""Operators: thin shells over the project's CLIs (background jobs) and result importers.

A background operator builds the CLI's arguments from the scene's settings (`commands`) and runs the
CLI as a job (`jobs`); when the run succeeds its results are imported into the scene it was started
from (`results`).  As Blender's own operators do, it runs in one of two ways:

- its button in Blender's window (`invoke`): the job runs in the background and the operator returns
  at once; the panel shows its progress, and the import happens when it ends;
- a script, or Blender in background mode (`execute`; ``bpy.ops.clothcapture.simulate()``,
  ``blender -b -P``): the operator returns when the job has ended and its results are imported,
  printing the job's log lines meanwhile; a failed run raises (RuntimeError, the CLI's error).

Bad settings are reported as errors before anything starts; a failing run shows the CLI's
``error: ...`` line in its panel.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, NamedTuple

import bpy
from bpy.props import IntProperty

from . import commands, jobs, library


def _results():
    """The importers: they need numpy and the project's packages, so they are imported on first use,
    after `library.ensure_importable` (the add-on registers before its preferences name the project)."""
    from . import results

    return results


class JobSpec(NamedTuple):
    """What an operator runs: the job's kind and label, the CLI's arguments and output folder,
    `importer(scene)` (imports the results, returns a message), the install's `extras` its tools
    need (`library.check_python`) and the progress bars the CLI shows (`jobs.Job.stages`)."""

    kind: str
    label: str
    argv: list[str]
    out: Path
    importer: Callable
    extras: tuple[str, ...] = ()
    stages: tuple[str, ...] = ()


class _Import(NamedTuple):
    """How a job's results are imported: its spec, the scene it was started from and the file opened
    then (`_files_opened`)."""

    spec: JobSpec
    scene_name: str
    file: int

    def scene(self):
        """The scene it was started from, None when another file was opened since."""
        return bpy.data.scenes.get(self.scene_name) if self.file == _files_opened else None


#: job id -> how its results are imported (`CLOTHCAPTURE_OT_import_results`)
_imports: dict[int, _Import] = {}
#: files opened in this session (File > Open, New, Revert; not Save, which keeps the scene open)
_files_opened = 0


@bpy.app.handlers.persistent
def _file_opened(*args) -> None:
    global _files_opened
    _files_opened += 1


def start(context, spec: JobSpec, wait: bool = False) -> jobs.Job:
    """Run `spec` as a job whose results are imported into this scene when it succeeds: in the
    background, or when `wait`, to its end (printing its log lines).

    The import is `CLOTHCAPTURE_OT_import_results`: after a background run it is one undo step of its
    own (Ctrl+Z takes back the import, not the user's change made meanwhile); inside an operator that
    waits, it is part of that operator's step.  Saving the file meanwhile changes nothing; when another
    file was opened, or the scene is gone, the results are offered (`Job.offered`: the panel's Import
    button puts them into the current scene)."""
    python = library.check_python(spec.extras)
    found = _Import(spec, context.scene.name, _files_opened)

    def on_success(job: jobs.Job) -> str:
        if found.scene() is None:
            job.offered = True
            return f"finished in {spec.out}; another file was opened since it started: Import puts its results " \
                   "into this one"
        try:
            bpy.ops.clothcapture.import_results("EXEC_DEFAULT", not wait, job_id=job.id)
        except RuntimeError as exc:  # the operator's error report
            raise RuntimeError(str(exc).strip().removeprefix("Error: ")) from None
        return job.message

    job = jobs.Job(spec.kind, spec.label, spec.argv, spec.out, on_success=on_success, stages=spec.stages)
    _imports[job.id] = found
    if wait:
        return jobs.run(job, python, library.project_root(), echo=print)
    return jobs.start(job, python, library.project_root())


def _import(scene, importer: Callable[[], str]) -> str:
    """Run `importer` (returns a message); what it made becomes the selection, framed (`scene.show`)."""
    from . import scene as build

    before = build.objects_state()
    message = importer()
    build.show(scene, build.made_since(before))
    return message


class _Background:
    """Mixin of the background operators: their static `prepare(context)` returns their `JobSpec`
    (`start(context, CLOTHCAPTURE_OT_simulate.prepare(context))` runs it in the background, as a button
    of Blender's window does)."""

    def invoke(self, context, event):
        return self.launch(context, wait=bpy.app.background)

    def execute(self, context):
        return self.launch(context, wait=True)

    def launch(self, context, wait: bool) -> set[str]:
        try:
            library.ensure_importable()
            return self.report_job(start(context, self.prepare(context), wait))
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}

    def report_job(self, job: jobs.Job) -> set[str]:
        """Report how `job` went (or that it started) as an operator's outcome."""
        if job.active:
            self.report({"INFO"}, f"{job.label}: started in the background")
        elif job.state == jobs.FINISHED:
            self.report({"INFO"}, f"{job.label}: {job.message}")
        else:
            self.report({"ERROR"} if job.state == jobs.FAILED else {"WARNING"},
                        f"{job.label}: {job.error or job.state.lower()}")
            return {"CANCELLED"}
        return {"FINISHED"}


class CLOTHCAPTURE_OT_generate_pattern(_Background, bpy.types.Operator):
    """Generate the printable two-level pattern (python -m assets.pattern)"""

    bl_idname = "clothcapture.generate_pattern"
    bl_label = "Generate Pattern"

    @staticmethod
    def prepare(context) -> JobSpec:
        argv, out = commands.pattern_command(context.scene.clothcapture)

        def importer(scene):
            width, height = _results().import_pattern(out).size
            return f"pattern.png {width} x {height} px in {out}"

        return JobSpec("pattern", "pattern", argv, out, importer, stages=commands.PATTERN_STAGES)


def _garment_job(settings, source: str, out: Path, level_mm: int, name: str | None):
    argv, out = commands.garment_command(settings, source, out, level_mm)

    def importer(scene):
        obj = _results().import_garment(scene, out, level_mm, name)
        obj["clothcapture_garment_source"] = source
        return f"{obj.name}: {len(obj.data.vertices)} vertices at {level_mm} mm, texture {out / 'pattern_texture.png'}"

    return JobSpec("garment", f"garment {Path(source).stem}", argv, out, importer, stages=commands.GARMENT_STAGES)


class CLOTHCAPTURE_OT_apply_pattern(_Background, bpy.types.Operator):
    """Apply the pattern to the selected meshes: a garment of this add-on is rebuilt with the pattern's
    pitch and seed (its texture is laid out per panel); any other mesh gets the printable pattern
    through its UV map"""

    bl_idname = "clothcapture.apply_pattern"
    bl_label = "Apply to Selected"
    bl_options = {"UNDO"}

    @classmethod
    def poll(cls, context):
        return any(obj.type == "MESH" for obj in context.selected_objects)

    def launch(self, context, wait: bool) -> set[str]:
        settings = context.scene.clothcapture
        meshes = [obj for obj in context.selected_objects if obj.type == "MESH"]
        garments = [obj for obj in meshes if "clothcapture_garment_source" in obj]
        try:
            library.ensure_importable()
            if len(garments) > 1:
                raise ValueError("select one garment at a time (each is rebuilt in the background)")
            for obj in meshes:
                if obj not in garments:
                    _results().apply_pattern(obj, commands.pattern_dir(settings))
            if garments:
                obj = garments[0]
                return self.report_job(start(context, _garment_job(
                    settings, obj["clothcapture_garment_source"], Path(obj["clothcapture_template"]).parent,
                    int(obj["clothcapture_level_mm"]), obj.name), wait))
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"pattern applied to {len(meshes)} mesh(es)")
        return {"FINISHED"}


class CLOTHCAPTURE_OT_import_motion(_Background, bpy.types.Operator):
    """Pose the body through the motion and import it as an animated mesh (python -m assets.motion preview)"""

    bl_idname = "clothcapture.import_motion"
    bl_label = "Import Motion"

    @staticmethod
    def prepare(context) -> JobSpec:
        settings = context.scene.clothcapture
        argv, out = commands.motion_command(settings)
        return JobSpec("motion", f"motion {commands.motion_name(settings)}", argv, out,
                       lambda scene: _results().import_motion(scene, out))


class CLOTHCAPTURE_OT_import_garment(_Background, bpy.types.Operator):
    """Build the garment's template at the chosen level with its pattern texture and import it
    (python -m assets.garments build)"""

    bl_idname = "clothcapture.import_garment"
    bl_label = "Import Garment"

    @staticmethod
    def prepare(context) -> JobSpec:
        settings = context.scene.clothcapture
        return _garment_job(settings, commands.garment_source(settings), commands.garment_dir(settings),
                            int(settings.garment.level_mm), None)


class CLOTHCAPTURE_OT_simulate(_Background, bpy.types.Operator):
    """Dress the garment on the body and simulate it through the motion (python -m factory.simulate);
    resumes what the simulation folder holds"""

    bl_idname = "clothcapture.simulate"
    bl_label = "Dress & Simulate"

    @staticmethod
    def prepare(context) -> JobSpec:
        settings = context.scene.clothcapture
        argv, out = commands.simulation_command(settings)
        return JobSpec("simulation", f"simulation {out.name}", argv, out,
                       lambda scene: _results().import_simulation(scene, out), stages=commands.SIMULATION_STAGES)


class CLOTHCAPTURE_OT_render(_Background, bpy.types.Operator):
    """Render the dataset or the capture with ground truth (python -m factory.dataset build | capture)"""

    bl_idname = "clothcapture.render"
    bl_label = "Render"

    @staticmethod
    def prepare(context) -> JobSpec:
        settings = context.scene.clothcapture
        rig = settings.render.rig
        argv, out = commands.render_command(settings)
        return JobSpec("render", f"{rig.lower()} {out.name}", argv, out,
                       lambda scene: _results().import_render(scene, out, rig), ("factory",),
                       commands.render_stages(settings))


def _review_options(settings) -> dict:
    review = settings.review
    return {"groundtruth_offset": review.groundtruth_offset if review.show_groundtruth else None,
            "heatmap_max_mm": review.heatmap_max_mm if review.heatmap else None, "cameras": review.import_cameras}


def _review_capture(settings) -> Path | None:
    """The capture to compare with: the Review panel's, else the Render panel's when it has ground truth."""
    try:
        capture = commands.capture_dir(settings)
    except ValueError:
        if settings.review.capture_dir:
            raise
        return None  # no output folder (an unsaved .blend): review without the ground truth
    return capture if (capture / "garment.npz").is_file() else None


class CLOTHCAPTURE_OT_reconstruct(_Background, bpy.types.Operator):
    """Reconstruct the capture (python -m reconstruction run) and import the result for review"""

    bl_idname = "clothcapture.reconstruct"
    bl_label = "Reconstruct"

    @staticmethod
    def prepare(context) -> JobSpec:
        settings = context.scene.clothcapture
        argv, out = commands.reconstruction_command(settings)
        capture, options = _review_capture(settings), _review_options(settings)
        extras = ("reconstruction",) + (("networks",) if settings.review.detections == "networks" else ())
        return JobSpec("reconstruction", f"reconstruction {out.name}", argv, out,
                       lambda scene: _results().import_reconstruction(scene, out, capture, **options), extras,
                       commands.RECONSTRUCTION_STAGES)


class CLOTHCAPTURE_OT_import_reconstruction(bpy.types.Operator):
    """Import a reconstruction folder for review: animated mesh with captured-vs-filled colours, the
    ground truth beside it and the per-vertex error heat map (with a capture), the cameras"""

    bl_idname = "clothcapture.import_reconstruction"
    bl_label = "Import Reconstruction"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        settings = context.scene.clothcapture
        try:
            library.ensure_importable()
            folder, capture = commands.reconstruction_dir(settings), _review_capture(settings)
            message = _import(context.scene, lambda: _results().import_reconstruction(
                context.scene, folder, capture, **_review_options(settings)))
        except (ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, message)
        return {"FINISHED"}


class CLOTHCAPTURE_OT_import_results(bpy.types.Operator):
    """Import the results of this finished run (into the scene it was started from, or this one when
    another file was opened since)"""

    bl_idname = "clothcapture.import_results"
    bl_label = "Import Results"
    bl_options = {"UNDO", "INTERNAL"}

    job_id: IntProperty()

    def execute(self, context):
        job, found = jobs.find(self.job_id), _imports.get(self.job_id)
        if job is None or found is None or job.returncode != 0:
            self.report({"ERROR"}, "no finished run to import")
            return {"CANCELLED"}
        scene = found.scene() or context.scene
        try:
            job.message = _import(scene, lambda: found.spec.importer(scene))
        except Exception as exc:  # bad or missing results: say what, keep the scene usable
            self.report({"ERROR"}, f"{type(exc).__name__}: {exc}")
            return {"CANCELLED"}
        job.offered = False
        self.report({"INFO"}, job.message)
        return {"FINISHED"}


class CLOTHCAPTURE_OT_cancel_job(bpy.types.Operator):
    """Stop this background run (files it finished stay whole; nothing half-written remains)"""

    bl_idname = "clothcapture.cancel_job"
    bl_label = "Cancel"

    job_id: IntProperty()

    def execute(self, context):
        job = jobs.find(self.job_id)
        if job is None:
            return {"CANCELLED"}
        jobs.cancel(job)
        return {"FINISHED"}


class CLOTHCAPTURE_OT_dismiss_job(bpy.types.Operator):
    """Clear this finished run's message"""

    bl_idname = "clothcapture.dismiss_job"
    bl_label = "Dismiss"

    job_id: IntProperty()

    def execute(self, context):
        job = jobs.find(self.job_id)
        if job is None or job.active:
            return {"CANCELLED"}
        jobs.dismiss(job)
        _imports.pop(job.id, None)
        return {"FINISHED"}


CLASSES = (CLOTHCAPTURE_OT_generate_pattern, CLOTHCAPTURE_OT_apply_pattern, CLOTHCAPTURE_OT_import_motion,
           CLOTHCAPTURE_OT_import_garment, CLOTHCAPTURE_OT_simulate, CLOTHCAPTURE_OT_render,
           CLOTHCAPTURE_OT_reconstruct, CLOTHCAPTURE_OT_import_reconstruction, CLOTHCAPTURE_OT_import_results,
           CLOTHCAPTURE_OT_cancel_job, CLOTHCAPTURE_OT_dismiss_job)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)


def register() -> None:
    _register_classes()
    bpy.app.handlers.load_post.append(_file_opened)


def unregister() -> None:
    if _file_opened in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_file_opened)
    _unregister_classes()
