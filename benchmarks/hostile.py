"""Hostile and careless input: run the `tests/hostile` suite and count what each kind of bad input got.

Every case of the suite builds a bad input (a crafted pickle, a name with `..`, a full disk part way,
a replaced resume input, a size that would allocate tens of GiB, a value that would be read wrongly,
a file that made a library raise) and runs the real CLI or loader on it.  A case *holds* when the input
got a clear error (or, for a value that is only suspicious, a warning) and nothing was written outside
the output folder or half written.  The table counts the cases by what they guard against; the
baseline beside it, in the same run, is the same cases run on the code before the guards (a git
worktree of `--baseline`, the suite copied in), where a case whose guard did not exist yet fails.

    python benchmarks/hostile.py [--baseline REV | --baseline none] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from common import add_results_flag, write_results

ROOT = Path(__file__).resolve().parents[1]
#: the last commit before the hostile-input guards
BASELINE_REV = "1f56bf8"

#: kind -> (what the case guards against, what a case that fails means)
KINDS = {
    "crash": ("memory corruption", "crash (signal)"),
    "outside": ("writes outside --out", "written outside --out"),
    "half": ("half files, mixed outputs", "half or mixed files"),
    "stale": ("resume on changed inputs", "stale resume"),
    "memory": ("memory bombs", "allocated before refusing"),
    "silent": ("silently wrong results", "silent acceptance"),
    "traceback": ("tracebacks from libraries", "traceback"),
}


class _Tally:
    """A pytest plugin that records each hostile case's kind and whether it held."""

    def __init__(self):
        self.kind: dict[str, str] = {}
        self.held: dict[str, bool] = {}

    def pytest_collection_modifyitems(self, items):
        for item in items:
            marker = item.get_closest_marker("hostile")
            self.kind[item.nodeid] = marker.args[0] if marker else "unmarked"

    def pytest_runtest_logreport(self, report):
        if report.when == "call" or report.failed:
            self.held[report.nodeid] = self.held.get(report.nodeid, True) and report.passed


def tally(tree: Path) -> dict[str, list]:
    """Run `tree`'s tests/hostile in this process: {test id: [kind, held]}."""
    plugin = _Tally()
    pytest.main(["-q", "-p", "no:cacheprovider", "--continue-on-collection-errors", "--rootdir", str(tree),
                 str(tree / "tests" / "hostile")],
                plugins=[plugin])
    return {node: [plugin.kind.get(node, "unmarked"), ok] for node, ok in plugin.held.items()}


def tally_baseline(rev: str) -> dict[str, list]:
    """The current suite run on the code of `rev` (a temporary git worktree), in a fresh process."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(tree), rev], check=True)
        try:
            shutil.rmtree(tree / "tests" / "hostile", ignore_errors=True)
            shutil.copytree(ROOT / "tests" / "hostile", tree / "tests" / "hostile")
            out = Path(tmp) / "counts.json"
            subprocess.run([sys.executable, __file__, "--tree", str(tree), "--counts", str(out)], cwd=tree,
                           env=dict(os.environ, PYTHONPATH=str(tree)), check=False)
            return json.loads(out.read_text())
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", default=BASELINE_REV,
                        help="git revision whose code the suite also runs on, or 'none' (default %(default)s)")
    parser.add_argument("--json", type=Path, help="also write the counts here")
    parser.add_argument("--tree", type=Path, default=ROOT, help=argparse.SUPPRESS)
    parser.add_argument("--counts", type=Path, help=argparse.SUPPRESS)
    add_results_flag(parser)
    args = parser.parse_args(argv)
    if args.counts:  # the baseline's worker process
        args.counts.write_text(json.dumps(tally(args.tree)))
        return 0
    t0 = time.perf_counter()
    cases = tally(args.tree)
    seconds = time.perf_counter() - t0
    # A case missing from the baseline's run did not even import there (its guard did not exist): not held.
    before = tally_baseline(args.baseline) if args.baseline != "none" else None
    counts: dict[str, dict[str, int]] = {}
    for node, (kind, ok) in cases.items():
        row = counts.setdefault(kind, {"cases": 0, "held": 0, "baseline_held": 0})
        row["cases"] += 1
        row["held"] += ok
        row["baseline_held"] += bool(before and before.get(node, [kind, False])[1])
    print(f"\n{platform.node()} {platform.machine()}, Python {platform.python_version()}, suite {seconds:.0f} s")
    table = [f"| guards against | cases | held | failed as | failed | baseline ({args.baseline}): held |",
             "|---|---:|---:|---|---:|---:|"]
    empty = {"cases": 0, "held": 0, "baseline_held": 0}
    for kind in [*KINDS, *sorted(set(counts) - set(KINDS))]:
        what, failure = KINDS.get(kind, (kind, kind))
        row = counts.get(kind, empty)
        table.append(f"| {what} | {row['cases']} | {row['held']} | {failure} | {row['cases'] - row['held']} | "
                     f"{row['baseline_held'] if before is not None else ''} |")
    total = sum(r["cases"] for r in counts.values())
    ok = sum(r["held"] for r in counts.values())
    base_ok = sum(r["baseline_held"] for r in counts.values())
    table.append(f"| **all** | **{total}** | **{ok}** | | **{total - ok}** | {base_ok if before is not None else ''} |")
    print("\n".join(table))
    result = {"benchmark": "hostile", "cases": total, "held": ok, "by_kind": counts, "baseline": args.baseline,
              "seconds": seconds}
    print(json.dumps(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    if ok != total:
        return 1
    if not args.no_results:
        baseline = f"; on the code before the guards ({args.baseline}) {base_ok} held" if before is not None else ""
        write_results("hostile", "\n".join(table), f"{ok} of {total} cases held (target: all){baseline}; "
                      f"suite {seconds:.0f} s.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
