"""Move a folder of files larger than one device call carries (64 MiB each way) in checked parts.

The GPU machine returns what a call writes under $OUT (at most 8 files of 16 MiB, 64 MiB in all) and
takes the working tree with what a call carries (64 MiB in all, the tree's own 4 MiB included), and
it goes back 30 s after a call: so trained weights (about 150 MB of slim checkpoints) and rendered
datasets travel in parts of 15 MiB, three a call, over quick back-to-back calls.  Standard library only (it
runs on the device machine's Python as well as here).

    pack SRC PARTS [--part-mb 15]     SRC's files (recursively) -> PARTS/part.NNN + PARTS/MANIFEST.json
                                      (each file's and each part's size and SHA-256)
    send PARTS TO [--parts 0-2]       copy the manifest and the chosen parts into TO (e.g. $OUT)
    unpack PARTS DEST                 check every part, join, check every file, write them under DEST
                                      (each file written atomically; missing or damaged parts are named
                                      and nothing is written)
    wait FILE [--timeout S]           return when FILE exists (exit 1 after S seconds)

A device session's weights, for instance (`benchmarks/train_networks.py --export-weights`):

    (a benchmark started in the background does not keep the machine: it goes back 30 s after a call
    returns, so the wait calls follow one another with nothing in between, or the benchmark is lost.
    Start it detached, `setsid nohup python3 ... > LOG 2>&1 < /dev/null &`, and have the same call
    check that it is alive and its log growing before it returns: a plain `nohup ... &` once left an
    empty log, and the queued wait calls spent the session's device time on nothing)
    call 2 (on the machine):  python3 benchmarks/device_files.py wait /tmp/bn/export/results.json --timeout 570
                              python3 benchmarks/device_files.py pack /tmp/bn/export/store /tmp/parts
                              python3 benchmarks/device_files.py send /tmp/parts $OUT --parts 0-2
    calls 3, 4 (at once):     python3 benchmarks/device_files.py send /tmp/parts $OUT --parts 3-5
    here:                     copy every call's files into one folder, then
                              python benchmarks/device_files.py unpack <that folder> .bench/weights

And back in, in a session that still has them (a new checkout lacks ignored folders such as .bench;
a call's carry holds at most 64 MiB, and a path it does not name is removed from the machine's
working tree, so each call copies its parts out of the tree at once):

    here:                     python benchmarks/device_files.py pack .bench/weights .bench/parts
    calls 1, 2 (at once):     carry .bench/parts/MANIFEST.json and three parts each;
                              mkdir -p /tmp/parts && cp .bench/parts/* /tmp/parts/
    call 3:                   carry the last parts and .bench/carry; cp as above, then
                              python3 benchmarks/device_files.py unpack /tmp/parts /tmp/init
                              python3 benchmarks/train_networks.py ... --init /tmp/init
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path

MANIFEST = "MANIFEST.json"
PART = "part.{:03d}"
CHUNK = 1 << 20


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK), b""):
            digest.update(block)
    return digest.hexdigest()


class _Joined:
    """The files `paths` read as one stream: `read(count)` returns `count` bytes (fewer at the end)."""

    def __init__(self, paths: list[Path]):
        self._paths, self._open = list(paths), None

    def read(self, count: int) -> bytes:
        blocks = []
        while count > 0 and (self._open is not None or self._paths):
            if self._open is None:
                self._open = open(self._paths.pop(0), "rb")
            block = self._open.read(count)
            if not block:
                self._open.close()
                self._open = None
            blocks.append(block)
            count -= len(block)
        return b"".join(blocks)

    def close(self) -> None:
        if self._open is not None:
            self._open.close()


def pack(src: Path, parts: Path, part_mb: float = 15.0) -> dict:
    """Write the files under `src` (sorted by relative path, concatenated) as parts of at most
    `part_mb` MiB in `parts`, with `MANIFEST.json`; returns the manifest."""
    src, parts = Path(src), Path(parts)
    if not src.is_dir():
        raise ValueError(f"{src}: not a folder")
    if part_mb <= 0:
        raise ValueError(f"--part-mb must be > 0, got {part_mb}")
    files = sorted(p for p in src.rglob("*") if p.is_file())
    if not files:
        raise ValueError(f"{src}: no files to pack")
    parts.mkdir(parents=True, exist_ok=True)
    size, joined, written = int(part_mb * (1 << 20)), _Joined(files), []
    while data := joined.read(size):
        written.append(parts / PART.format(len(written)))
        written[-1].write_bytes(data)
    manifest = {"files": [{"path": p.relative_to(src).as_posix(), "bytes": p.stat().st_size, "sha256": _sha256(p)}
                          for p in files],
                "parts": [{"name": p.name, "bytes": p.stat().st_size, "sha256": _sha256(p)} for p in written]}
    (parts / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return manifest


def _read_manifest(parts: Path) -> dict:
    path = Path(parts) / MANIFEST
    if not path.is_file():
        raise ValueError(f"{parts}: no {MANIFEST} (not a folder written by `pack`)")
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not a manifest of `pack` ({exc})") from exc
    if not isinstance(manifest, dict) or not {"files", "parts"} <= manifest.keys():
        raise ValueError(f"{path}: not a manifest of `pack` (it needs 'files' and 'parts')")
    return manifest


def _numbers(spec: str, count: int) -> list[int]:
    """Part numbers of 'a-b,c' (inclusive ranges), within the `count` parts."""
    chosen = []
    for item in spec.split(","):
        first, _, last = item.strip().partition("-")
        try:
            chosen += list(range(int(first), int(last or first) + 1))
        except ValueError as exc:
            raise ValueError(f"--parts: {spec!r} is not like 0-2,5") from exc
    outside = [n for n in chosen if not 0 <= n < count]
    if outside:
        raise ValueError(f"--parts: there are {count} parts (0-{count - 1}); {outside} are not among them")
    return chosen


def send(parts: Path, to: Path, numbers: str | None = None) -> list[Path]:
    """Copy the manifest and the parts `numbers` ('0-2,5'; default all) from `parts` into `to`."""
    parts, to = Path(parts), Path(to)
    manifest = _read_manifest(parts)
    chosen = _numbers(numbers, len(manifest["parts"])) if numbers else range(len(manifest["parts"]))
    to.mkdir(parents=True, exist_ok=True)
    copied = [Path(shutil.copy2(parts / MANIFEST, to / MANIFEST))]
    for n in chosen:
        copied.append(Path(shutil.copy2(parts / manifest["parts"][n]["name"], to / manifest["parts"][n]["name"])))
    return copied


def unpack(parts: Path, dest: Path) -> list[Path]:
    """Check the parts in `parts` against the manifest, join them and write the files under `dest`
    (each checked, then renamed into place); raises naming every missing or damaged part first."""
    parts, dest = Path(parts), Path(dest)
    manifest = _read_manifest(parts)
    problems = []
    for part in manifest["parts"]:
        path = parts / part["name"]
        if not path.is_file():
            problems.append(f"{part['name']} is missing")
        elif path.stat().st_size != part["bytes"] or _sha256(path) != part["sha256"]:
            problems.append(f"{part['name']} is damaged (size or SHA-256 differs from {MANIFEST})")
    if problems:
        raise ValueError(f"{parts}: " + "; ".join(problems))
    for entry in manifest["files"]:
        target = (dest / entry["path"]).resolve()
        if dest.resolve() not in target.parents:
            raise ValueError(f"{parts / MANIFEST}: {entry['path']!r} lies outside the destination")
    joined, written = _Joined([parts / part["name"] for part in manifest["parts"]]), []
    for entry in manifest["files"]:
        target = dest / entry["path"]
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(target.name + ".part")
        digest, left = hashlib.sha256(), entry["bytes"]
        with open(partial, "wb") as out:
            while left:
                block = joined.read(min(CHUNK, left))
                if not block:  # the parts, each of its checked size, hold fewer bytes than the files
                    raise ValueError(f"{parts / MANIFEST}: the parts end before {entry['path']} does")
                digest.update(block)
                out.write(block)
                left -= len(block)
        if digest.hexdigest() != entry["sha256"]:
            partial.unlink()
            raise ValueError(f"{parts}: {entry['path']} joined from the parts does not match its SHA-256")
        os.replace(partial, target)
        written.append(target)
    joined.close()
    return written


def wait(path: Path, timeout_s: float) -> bool:
    """Whether `path` exists within `timeout_s` seconds (checked every second)."""
    deadline = time.monotonic() + timeout_s
    while not Path(path).exists():
        if time.monotonic() >= deadline:
            return False
        time.sleep(1.0)
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("pack", help="a folder's files -> checked parts")
    p.add_argument("src", type=Path)
    p.add_argument("parts", type=Path)
    p.add_argument("--part-mb", type=float, default=15.0, help="largest part, MiB (16 at most come back)")
    p = sub.add_parser("send", help="copy the manifest and some parts")
    p.add_argument("parts", type=Path)
    p.add_argument("to", type=Path)
    p.add_argument("--parts", dest="numbers", help="part numbers, e.g. 0-2,5 (default: all)")
    p = sub.add_parser("unpack", help="check and join parts into files")
    p.add_argument("parts", type=Path)
    p.add_argument("dest", type=Path)
    p = sub.add_parser("wait", help="wait for a file")
    p.add_argument("path", type=Path)
    p.add_argument("--timeout", type=float, default=570.0, help="seconds")
    args = parser.parse_args(argv)
    try:
        if args.command == "pack":
            manifest = pack(args.src, args.parts, args.part_mb)
            print(f"{len(manifest['files'])} files in {len(manifest['parts'])} parts in {args.parts}")
        elif args.command == "send":
            print("\n".join(str(p) for p in send(args.parts, args.to, args.numbers)))
        elif args.command == "unpack":
            print("\n".join(str(p) for p in unpack(args.parts, args.dest)))
        elif not wait(args.path, args.timeout):
            print(f"{args.path}: not there after {args.timeout:.0f} s", file=sys.stderr)
            return 1
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
