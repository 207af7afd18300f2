"""Long work in a background process: the project's command-line tools, run by the project's Python.

A `Job` is one CLI run (``python -m factory.simulate ...``) whose stdout and stderr go to a log file.
`tick` reads what each running job has written since the last call:

- progress: of the whole job, from its tqdm bars (``simulating shirt:  40%|####  | 2/5 [...]``): a job
  knows the bars its CLI shows, in order (`Job.stages`, their descriptions' beginnings), and its
  progress is the current bar's place among them plus that bar's fraction; a bar that is cleared
  (``leave=False``: sewing that converged early) or followed by a later one counts as done, and
  progress never goes back.  The text is the current bar's (``simulating shirt 2/5``);
- status: the last logging line (``INFO factory.dressing: dressed shirt ...``), and `Job.log` the
  last `LOG_LINES` of them;
- errors: a CLI reports bad input as ``error: ...`` on stderr with a non-zero exit status
  (`assets.cli.run_cli`); that line (or the last line of a traceback) becomes `Job.error`.

When a job ends with status 0 its `on_success` callback runs in Blender's main thread (inside `tick`)
and imports the results into the scene; an exception there fails the job with that message.

Cancelling sends SIGINT to the job's process group (Python unwinds, so `assets.fileio.atomic_path`
deletes its temporary file and every finished file is whole), then SIGKILL after `KILL_AFTER_S`; any
``.*.part`` temporary left by a killed writer is then removed from the job's output folder.

In Blender a `bpy.app.timers` timer calls `tick` every `POLL_S` seconds while a job started by `start`
is active; `run` (a script, Blender in background mode) and `wait` run the same `tick` until the job
is done.
"""

from __future__ import annotations

import atexit
import itertools
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

POLL_S = 0.25
KILL_AFTER_S = 5.0
#: how many of the last output lines a job keeps (shown when it fails without an ``error:`` line)
TAIL_LINES = 20
#: how many logging messages a job keeps
LOG_LINES = 200

RUNNING, CANCELLING = "RUNNING", "CANCELLING"
FINISHED, FAILED, CANCELLED = "FINISHED", "FAILED", "CANCELLED"
ACTIVE = (RUNNING, CANCELLING)

_TQDM = re.compile(r"^(?P<desc>.*?):\s*(?P<percent>\d+)%\|.*?\|\s*(?P<n>\d+)/(?P<total>\d+)")
_LOG = re.compile(r"^(?:DEBUG|INFO|WARNING|ERROR|CRITICAL) [\w.]+: (?P<message>.*)$")
_ids = itertools.count(1)


@dataclass(eq=False)
class Job:
    """One background CLI run.  argv: the arguments after the Python executable (``-m module ...``);
    out: the folder it writes (cleaned of temporaries when cancelled); on_success: called with the
    job when the process exits with status 0, returns a message for the UI; stages: the beginnings of
    the descriptions of the progress bars the CLI shows, in order (module docstring)."""

    kind: str
    label: str
    argv: list[str]
    out: Path
    on_success: Callable[["Job"], str] | None = None
    stages: tuple[str, ...] = ()
    id: int = field(default_factory=lambda: next(_ids))
    state: str = RUNNING
    progress: float | None = None
    progress_text: str = ""
    status: str = ""
    error: str = ""
    message: str = ""
    returncode: int | None = None
    log_path: Path | None = None
    started: float = 0.0
    ended: float | None = None
    tail: list[str] = field(default_factory=list)
    log: list[str] = field(default_factory=list)
    logged: int = 0  #: logging lines read so far (`log` keeps the last `LOG_LINES`)
    offered: bool = False  #: finished, its results wait for the user to import them
    _process: subprocess.Popen | None = None
    _offset: int = 0
    _partial: str = ""
    _kill_at: float | None = None
    _stage: int = -1
    _bar_n: int = 0

    @property
    def active(self) -> bool:
        return self.state in ACTIVE

    @property
    def seconds(self) -> float:
        return (self.ended or time.monotonic()) - self.started

    def read_output(self) -> None:
        """Take in what the process wrote since the last call: progress, status, error, tail."""
        if self.log_path is None or not self.log_path.exists():
            return
        with open(self.log_path, "rb") as log:
            log.seek(self._offset)
            chunk = log.read()
        self._offset += len(chunk)
        parts = re.split(r"[\r\n]", self._partial + chunk.decode("utf-8", errors="replace"))
        self._partial = parts.pop()  # a tqdm bar is rewritten after a carriage return: read it as it stands
        for line in parts + [self._partial]:
            if line and not line.strip():  # a bar cleared on closing
                self._advance(self._stage + 1.0)
            self._parse(line.strip())
        self.tail = (self.tail + [p.strip() for p in parts if p.strip()])[-TAIL_LINES:]

    def _parse(self, line: str) -> None:
        if not line:
            return
        bar = _TQDM.match(line)
        if bar:
            self._bar(bar["desc"].strip(), int(bar["n"]), int(bar["total"]))
        elif line.startswith("error: "):
            self.error = line[len("error: "):]
        else:
            logged = _LOG.match(line)
            if logged and logged["message"] != self.status:  # (a partial line is read again when complete)
                self.status = logged["message"]
                self.log = (self.log + [self.status])[-LOG_LINES:]
                self.logged += 1


    def _bar(self, desc: str, n: int, total: int) -> None:
        self.progress_text = f"{desc} {n}/{total}"
        if not self.stages:
            self.progress = n / total if total else None
            return
        same = self._stage >= 0 and desc.startswith(self.stages[self._stage]) and n >= self._bar_n
        if not same:  # a new bar: the next stage it begins (those skipped were done before, a resumed run)
            later = [i for i in range(self._stage + 1, len(self.stages)) if desc.startswith(self.stages[i])]
            if later:
                self._stage = later[0]
            elif not (self._stage >= 0 and desc.startswith(self.stages[self._stage])):
                return  # a bar of no stage: its text shows, the progress stays
        self._bar_n = n
        self._advance(self._stage + (n / total if total else 0.0))

    def _advance(self, stages_done: float) -> None:
        """Progress at `stages_done` stages of `stages` (never backwards)."""
        if self.stages and self._stage >= 0:
            self.progress = max(self.progress or 0.0, min(1.0, stages_done / len(self.stages)))


_jobs: list[Job] = []


def jobs(kind: str | None = None) -> list[Job]:
    """The jobs of this session (of `kind`), oldest first."""
    return [job for job in _jobs if kind is None or job.kind == kind]


def active(kind: str | None = None) -> list[Job]:
    return [job for job in jobs(kind) if job.active]


def latest(kind: str) -> Job | None:
    found = jobs(kind)
    return found[-1] if found else None


def find(job_id: int) -> Job | None:
    return next((job for job in _jobs if job.id == job_id), None)


def start(job: Job, python: str, cwd: Path) -> Job:
    """Start `job` with the interpreter `python` in folder `cwd` (the project root), in the background
    (Blender's timer follows it); one active job per kind (ValueError otherwise)."""
    _spawn(job, python, cwd)
    _ensure_timer()
    return job


def run(job: Job, python: str, cwd: Path, echo: Callable[[str], None] | None = None) -> Job:
    """Run `job` as `start` does, but to its end (a script, Blender in background mode): `wait`
    without a time limit, `echo` taking its log lines; interrupted (Ctrl+C), the job is cancelled."""
    _spawn(job, python, cwd)
    try:
        return wait(job, None, echo)
    except KeyboardInterrupt:
        cancel(job)
        wait(job, 2 * KILL_AFTER_S)
        raise


def _spawn(job: Job, python: str, cwd: Path) -> None:
    busy = active(job.kind)
    if busy:
        raise ValueError(f"{busy[0].label} is still running: wait for it or cancel it first")
    fd, log = tempfile.mkstemp(prefix=f"clothcapture-{job.kind}-", suffix=".log")
    job.log_path = Path(log)
    env = {**os.environ, "PYTHONUNBUFFERED": "1",
           "PYTHONPATH": os.pathsep.join([str(cwd)] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    options = {"start_new_session": True} if os.name == "posix" else \
        {"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP}
    try:
        job._process = subprocess.Popen([python, *job.argv], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                                        stdout=fd, stderr=subprocess.STDOUT, **options)
    except OSError as exc:
        job.log_path.unlink(missing_ok=True)
        raise ValueError(f"cannot start {python}: {exc}") from exc
    finally:
        os.close(fd)
    job.started = time.monotonic()
    _jobs.append(job)


def cancel(job: Job) -> None:
    """Ask `job` to stop (SIGINT to its process group); `tick` kills it after `KILL_AFTER_S`."""
    if job.state != RUNNING:
        return
    job.state, job._kill_at = CANCELLING, time.monotonic() + KILL_AFTER_S
    _signal(job, signal.SIGINT if os.name == "posix" else signal.CTRL_BREAK_EVENT)


def dismiss(job: Job) -> None:
    """Forget a finished job and delete its log."""
    if job.active:
        raise ValueError(f"{job.label} is still running")
    if job.log_path is not None:
        job.log_path.unlink(missing_ok=True)
    _jobs.remove(job)


def _signal(job: Job, sig: int) -> None:
    process = job._process
    if process is None or process.poll() is not None:
        return
    try:
        if os.name == "posix":
            os.killpg(process.pid, sig)  # the process and whatever it started (its own group)
        elif sig == signal.SIGTERM:
            process.kill()
        else:
            process.send_signal(sig)
    except (ProcessLookupError, PermissionError, OSError):
        pass  # it ended meanwhile


def tick() -> bool:
    """Update every active job; finish those whose process ended.  True while any is active."""
    _update()
    _redraw()
    return bool(active())


def _update() -> None:
    for job in active():
        job.read_output()
        code = job._process.poll()
        if code is None:
            if job.state == CANCELLING and time.monotonic() >= job._kill_at:
                _signal(job, signal.SIGKILL if os.name == "posix" else signal.SIGTERM)
            continue
        job.returncode, job.ended = code, time.monotonic()
        job.read_output()
        if job.state == CANCELLING:
            job.state, job.progress = CANCELLED, None
            remove_temporaries(job.out)
        elif code != 0:
            _fail(job, job.error or (job.tail[-1] if job.tail else "no output"))
        else:
            _succeed(job)


def _succeed(job: Job) -> None:
    try:
        job.message = job.on_success(job) if job.on_success else ""
    except Exception as exc:  # the import into Blender failed: show why, keep the log
        _fail(job, f"the run finished but importing its results failed: {exc}")
        return
    job.state, job.progress = FINISHED, 1.0
    if job.log_path is not None:
        job.log_path.unlink(missing_ok=True)
        job.log_path = None


def _fail(job: Job, reason: str) -> None:
    job.state, job.progress = FAILED, None
    job.error = f"{reason} (exit status {job.returncode}; log {job.log_path})"
    print(f"clothcapture: {job.label} failed: {job.error}", file=sys.stderr)


def remove_temporaries(folder: Path) -> list[Path]:
    """Delete the temporaries of `assets.fileio.atomic_path` (``.<name>.<random>.part``) below `folder`."""
    removed = []
    if folder.is_dir():
        for path in folder.rglob(".*.part"):
            if path.is_file():
                path.unlink(missing_ok=True)
                removed.append(path)
    return removed


def wait(job: Job, timeout_s: float | None, echo: Callable[[str], None] | None = None) -> Job:
    """Run `tick` until `job` is done (what the timer does in Blender), passing each new log line and
    the outcome to `echo`; TimeoutError after `timeout_s` (None: no limit)."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    shown = 0
    while True:
        tick()
        if echo is not None:
            for line in job.log[len(job.log) - min(job.logged - shown, len(job.log)):]:
                echo(f"{job.label}: {line}")
            shown = job.logged
        if not job.active:
            if echo is not None:
                echo(f"{job.label}: {job.state.lower()}: {job.message if job.state == FINISHED else job.error}")
            return job
        if deadline is not None and time.monotonic() > deadline:
            raise TimeoutError(f"{job.label} did not finish within {timeout_s:g} s: {job.progress_text} {job.status}")
        time.sleep(0.1)


def stop_all() -> None:
    """Cancel every active job and wait until each has stopped (Blender closing: registered with
    `atexit`, so no run outlives the session that started it)."""
    for job in active():
        cancel(job)
    deadline = time.monotonic() + 2 * KILL_AFTER_S
    while active() and time.monotonic() < deadline:
        _update()
        time.sleep(0.05)


def shutdown() -> None:
    """Stop every job and the timer (the add-on is disabled)."""
    stop_all()
    _remove_timer()


atexit.register(stop_all)


# ---- Blender's side: the timer and redraws --------------------------------------------------------
def _timer() -> float | None:
    return POLL_S if tick() else None


def _ensure_timer() -> None:
    import bpy

    if not bpy.app.timers.is_registered(_timer):
        bpy.app.timers.register(_timer, first_interval=POLL_S, persistent=True)


def _remove_timer() -> None:
    import bpy

    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)


def _redraw() -> None:
    import bpy

    for window in getattr(bpy.context.window_manager, "windows", ()):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()
