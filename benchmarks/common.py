"""Shared by the benchmark scripts: run a snippet in a fresh Python process and collect its results,
so that each measurement's time and peak memory (max RSS) are its own."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

_RUNNER = """
import json, resource, time
R = {{}}
_start = time.perf_counter()
{body}
R["wall_s"] = time.perf_counter() - _start
R["peak_rss_gib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print("RESULT " + json.dumps(R))
"""


def run_fresh(body: str) -> dict:
    """Run `body` (which fills the dict `R`) in a new interpreter; return R plus wall_s, peak_rss_gib."""
    code = _RUNNER.format(body=textwrap.dedent(body))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    line = [l for l in out.stdout.splitlines() if l.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])
