"""Shared by the benchmark scripts: run a snippet in a fresh Python process and collect its results,
so that each measurement's time and peak memory (max RSS) are its own; and write a finished run's
table into its own section of `benchmarks/RESULTS.md`, so that `make bench` keeps the datasheet current.

A benchmark's section lies between two marker lines, ``<!-- bench:NAME -->`` and
``<!-- /bench:NAME -->``; `write_results` replaces what is between them (or appends the section when
the file has none) and leaves every other line of the file as it was.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "RESULTS.md"

_RUNNER = """
import json, resource, time
R = {{}}
_start = time.perf_counter()
{body}
R["wall_s"] = time.perf_counter() - _start
R["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print("RESULT " + json.dumps(R))
"""

#: a marker line: ``<!-- bench:NAME -->`` opens NAME's section, ``<!-- /bench:NAME -->`` closes it
_MARKER = re.compile(r"^<!-- (/?)bench:([A-Za-z0-9_.-]+) -->$")


def run_fresh(body: str) -> dict:
    """Run `body` (which fills the dict `R`) in a new interpreter; return R plus wall_s, peak_rss_gib."""
    code = _RUNNER.format(body=textwrap.dedent(body))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    line = [l for l in out.stdout.splitlines() if l.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def add_results_flag(parser: argparse.ArgumentParser) -> None:
    """--no-results: print the table only, leaving RESULTS.md as it is."""
    parser.add_argument("--no-results", action="store_true",
                        help="do not write this run's table into benchmarks/RESULTS.md")


def machine_description() -> str:
    """This machine in words: architecture, CPU cores, memory, Python (and the GPUs torch sees, if any)."""
    memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    words = [platform.machine(), f"{os.cpu_count()} CPU cores", f"{memory:.0f} GiB",
             f"Python {platform.python_version()}"]
    torch = sys.modules.get("torch")  # only when the benchmark imported it: never import torch for this
    if torch is not None and torch.cuda.is_available():
        names = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
        words.append(", ".join(f"{names.count(n)} x {n}" for n in dict.fromkeys(names)))
    return ", ".join(words)


def run_command() -> str:
    """The command line that started this process, as a reader would type it from the repository root."""
    python = Path(os.path.abspath(sys.executable))  # not resolved: a venv's python is a link out of it
    if python.is_relative_to(ROOT):
        python = python.relative_to(ROOT)
    script = Path(sys.argv[0]).resolve()
    argv0 = str(script.relative_to(ROOT)) if script.is_relative_to(ROOT) else sys.argv[0]
    return shlex.join([str(python), argv0, *sys.argv[1:]])


def results_section(name: str, table: str, stands: str, *, command: str | None = None,
                    machine: str | None = None, date: str | None = None) -> str:
    """Benchmark `name`'s section of RESULTS.md, marker lines included: date, machine, the exact
    command, the table, and one line on where it stands against its target."""
    if not _MARKER.match(f"<!-- bench:{name} -->"):
        raise ValueError(f"benchmark name {name!r}: expected letters, digits, '_', '.' or '-'")
    lines = [f"<!-- bench:{name} -->",
             f"- Date: {date or time.strftime('%Y-%m-%d')}",
             f"- Machine: {machine or machine_description()}",
             f"- Command: `{command or run_command()}`",
             "",
             table.strip("\n"),
             "",
             f"Where it stands: {stands.strip()}",
             f"<!-- /bench:{name} -->"]
    return "\n".join(lines) + "\n"


def _sections(lines: list[str], source: Path) -> dict[str, tuple[int, int]]:
    """{name: (index of its opening line, index of its closing line)}; a marker without its partner,
    a section opened inside another, or the same name twice raises ValueError naming the line."""
    found: dict[str, tuple[int, int]] = {}
    opened: tuple[str, int] | None = None
    for index, line in enumerate(lines):
        match = _MARKER.match(line.strip())
        if not match:
            continue
        closing, name = match.group(1) == "/", match.group(2)
        where = f"{source}: line {index + 1}"
        if not closing:
            if opened is not None:
                raise ValueError(f"{where}: section {name!r} opens inside section {opened[0]!r} "
                                 f"(opened at line {opened[1] + 1}, never closed)")
            if name in found:
                raise ValueError(f"{where}: a second section {name!r} (the first is at line {found[name][0] + 1})")
            opened = (name, index)
        elif opened is None or opened[0] != name:
            raise ValueError(f"{where}: <!-- /bench:{name} --> closes a section that is not open")
        else:
            found[name] = (opened[1], index)
            opened = None
    if opened is not None:
        raise ValueError(f"{source}: line {opened[1] + 1}: <!-- bench:{opened[0]} --> has no "
                         f"<!-- /bench:{opened[0]} --> after it")
    return found


def write_results(name: str, table: str, stands: str, *, path: str | os.PathLike = RESULTS,
                  command: str | None = None, machine: str | None = None, date: str | None = None) -> None:
    """Replace benchmark `name`'s section of `path` (RESULTS.md) with this run's, or append it when the
    file has none; every other line stays as it was.  Call it only after a successful run.  The file is
    written atomically; malformed markers anywhere in it are refused (ValueError naming the line) before
    anything is written."""
    from assets.fileio import atomic_path

    path = Path(path)
    text = path.read_text() if path.exists() else ""
    lines = text.splitlines(keepends=True)
    section = results_section(name, table, stands, command=command, machine=machine, date=date)
    sections = _sections([line.rstrip("\n") for line in lines], path)
    if name in sections:
        first, last = sections[name]
        lines[first:last + 1] = [section]
    else:
        if lines and not lines[-1].endswith("\n"):
            lines[-1] += "\n"
        lines.append(("\n" if lines else "") + section)
    with atomic_path(path) as tmp:
        tmp.write_text("".join(lines))
