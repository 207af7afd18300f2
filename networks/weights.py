"""The project's trained weights, kept in the repository's history but never in its working tree.

Trained networks are too large for the working tree (the stored compact checkpoints are about 100 MB, and
the tree travels whole to the GPU machine, 64 MiB a call), and nothing outside the repository
outlives a session.  So `store` writes them as an orphan commit (a commit with no parent whose tree
holds only the checkpoints) and joins it to the current branch by a merge commit that keeps the
branch's tree and adds `networks/weights.json`, the manifest: per network, the file, the orphan commit
and the file's SHA-256.  A clone with history (`git clone`, not `--depth`) carries them; `fetch`
writes them out, checked::

    python -m networks.checkpoint slim --int8 runs/loc/last.pt store/localizer.pt   # each network
    cp runs/reader/recipe.json store/reader.recipe.json                              # trained from a recipe
    python -m networks.weights store store/ --source "eighteenth GPU run"            # commits them
    python -m networks.weights fetch --out out/weights                               # any clone

Store only compact (int8) checkpoints, and only when they beat the ones in the manifest: every stored
set stays in the history of every clone.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
from pathlib import Path

from assets.fileio import atomic_path, safe_name

FORMAT = "clothcapture-weights"
VERSION = 1
#: the networks a manifest holds, each stored as <name>.pt, and their tasks: `recognizer` classifies the
#: default shirt's IDs, `reader` reads a marker's code modules and serves any garment of the codebook
NETWORKS = {"localizer": "localizer", "recognizer": "recognizer", "reader": "recognizer",
            "crosspoints": "crosspoints"}
#: the manifest, relative to the repository's root
MANIFEST = Path("networks") / "weights.json"
#: the largest set `store` takes: each stored set stays in every clone's history
MAX_STORE_BYTES = 100 * 2**20


def _git(root: Path, *args: str, stdin: bytes | None = None) -> bytes:
    """Run git in `root`; its stdout.  A failure raises ValueError with git's own message."""
    done = subprocess.run(["git", "-C", str(root), *args], input=stdin, capture_output=True)
    if done.returncode != 0:
        message = done.stderr.decode(errors="replace").strip().splitlines()
        raise ValueError(f"{root}: git {' '.join(args[:2])} failed: {message[-1] if message else done.returncode}")
    return done.stdout


def repository_root(start: str | Path | None = None) -> Path:
    """The root of the git repository holding `start` (default: this package's)."""
    start = Path(start) if start is not None else Path(__file__).resolve().parent
    return Path(_git(start, "rev-parse", "--show-toplevel").decode().strip())


def file_sha256(path: Path) -> str:
    """The SHA-256 of a file's bytes, in hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_manifest(root: Path) -> dict:
    """The manifest at `root`/networks/weights.json ({"weights": {}} when there is none), checked."""
    path = root / MANIFEST
    if not path.is_file():
        return {"format": FORMAT, "version": VERSION, "weights": {}}
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON ({exc})") from exc
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("version") != VERSION:
        raise ValueError(f"{path}: not a {FORMAT} manifest of version {VERSION}")
    weights = data.get("weights", {})
    if not isinstance(weights, dict):
        raise ValueError(f"{path}: weights must be an object of task: entry")
    for name, entry in weights.items():
        missing = [k for k in ("file", "commit", "sha256", "bytes") if k not in entry] if isinstance(entry, dict) \
            else ["file", "commit", "sha256", "bytes"]
        if name not in NETWORKS or missing:
            raise ValueError(f"{path}: weights[{name!r}] " + (f"lacks {', '.join(missing)}" if missing
                                                             else f"is not one of {', '.join(NETWORKS)}"))
        safe_name(entry["file"], f"{path}: weights[{name!r}].file")  # `fetch` writes it into its --out
    return data


def store(folder: str | Path, root: str | Path | None = None, source: str = "") -> dict:
    """Commit the checkpoints `folder`/<name>.pt (any of NETWORKS) into the history of the repository at
    `root` (default: this package's) and record them in its manifest; returns the new manifest.

    Each file must be one of our checkpoints of that name's task (`read_checkpoint`); a reader's must read
    code modules, a recognizer's classify IDs.  A network trained from a recipe (`networks.train
    --recipe`) has its run's record beside it as `folder`/<name>.recipe.json; its entry then names the
    recipe, the recipe file's SHA-256 and the digest of the data it trained on.
    Networks not in `folder` keep their manifest entries.  Refused while anything is staged (the merge commit takes the index
    as it is) or when the files exceed MAX_STORE_BYTES together."""
    from networks.checkpoint import read_checkpoint

    folder = Path(folder)
    root = repository_root(root)
    files = {name: folder / f"{name}.pt" for name in NETWORKS if (folder / f"{name}.pt").is_file()}
    if not files:
        raise ValueError(f"{folder}: holds none of {', '.join(n + '.pt' for n in NETWORKS)}")
    total = sum(path.stat().st_size for path in files.values())
    if total > MAX_STORE_BYTES:
        raise ValueError(f"{folder}: {total / 2**20:.0f} MiB of checkpoints, more than {MAX_STORE_BYTES // 2**20} "
                         "MiB; store compact ones (python -m networks.checkpoint slim --int8)")
    records = {}
    for name, path in files.items():
        task = NETWORKS[name]
        data = read_checkpoint(path)
        if data["task"] != task:
            raise ValueError(f"{path}: a {data['task']} checkpoint under the name {name}.pt")
        if task == "recognizer" and (data["config"].get("recognizer_classes") == "modules") != (name == "reader"):
            raise ValueError(f"{path}: " + ("an ID classifier under the name reader.pt" if name == "reader" else
                                            "a module reader under the name recognizer.pt (store it as reader.pt)"))
        records[name] = {"step": int(data["step"]), "int8": bool(data.get("int8_scales")),
                         "codebook_hash": data["pattern"]["codebook_hash"]}
        record_path = folder / f"{name}.recipe.json"
        if record_path.is_file():
            run = json.loads(record_path.read_text())
            if not isinstance(run, dict) or run.get("task") != task or \
                    not all(isinstance(run.get(k), str) for k in ("recipe", "file_sha256", "data_digest")):
                raise ValueError(f"{record_path}: not the recipe.json of a {task} run of networks.train --recipe")
            records[name]["recipe"] = {k: run[k] for k in ("recipe", "file_sha256", "data_digest")}
    if _git(root, "diff", "--cached", "--name-only").strip():
        raise ValueError(f"{root}: the index holds staged changes; commit or unstage them before storing weights")

    lines = []
    for task, path in files.items():
        blob = _git(root, "hash-object", "-w", str(path.resolve())).decode().strip()
        lines.append(f"100644 blob {blob}\t{path.name}\n")
    tree = _git(root, "mktree", stdin="".join(lines).encode()).decode().strip()
    message = f"Weights: {', '.join(files)}" + (f" ({source})" if source else "")
    orphan = _git(root, "commit-tree", tree, "-m", message).decode().strip()

    manifest = read_manifest(root)
    for name, path in files.items():
        manifest["weights"][name] = {"file": path.name, "commit": orphan, "sha256": file_sha256(path),
                                     "bytes": path.stat().st_size, "source": source, **records[name]}
    target = root / MANIFEST
    with atomic_path(target) as tmp:
        Path(tmp).write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    head = _git(root, "rev-parse", "HEAD").decode().strip()
    _git(root, "add", str(MANIFEST))
    merged_tree = _git(root, "write-tree").decode().strip()
    merge = _git(root, "commit-tree", merged_tree, "-p", head, "-p", orphan, "-m",
                 f"{message}: joined to the history, listed in {MANIFEST.as_posix()}").decode().strip()
    _git(root, "update-ref", "-m", "networks.weights store", "HEAD", merge, head)
    return manifest


def fetch_blob(root: Path, commit: str, file: str, sha256: str, target: Path, what: str) -> Path:
    """Write `commit`:`file` of the repository at `root` to `target`, checked against `sha256` (a file
    already there with that hash is kept); `what` names the weights in errors."""
    if target.is_file() and file_sha256(target) == sha256:
        return target
    if subprocess.run(["git", "-C", str(root), "cat-file", "-e", f"{commit}^{{commit}}"],
                      capture_output=True).returncode != 0:
        raise ValueError(f"{root}: lacks commit {commit[:12]} holding the {what} weights "
                         "(a shallow clone? run git fetch --unshallow)")
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(target) as tmp:
        Path(tmp).write_bytes(_git(root, "cat-file", "blob", f"{commit}:{file}"))
        if file_sha256(Path(tmp)) != sha256:
            raise ValueError(f"{root}: {commit[:12]}:{file} does not match the {what} weights' SHA-256")
    return target


def fetch(out: str | Path, root: str | Path | None = None, names: tuple[str, ...] | None = None) -> dict[str, Path]:
    """Write the manifest's checkpoints `names` (default: all it holds) to `out`/<file> from the
    repository's history, each checked against its SHA-256; {name: path}.  A file already there with
    the right hash is kept."""
    root = repository_root(root)
    manifest = read_manifest(root)["weights"]
    names = tuple(manifest) if names is None else names
    missing = [n for n in names if n not in manifest]
    if missing:
        raise ValueError(f"{root / MANIFEST}: no stored weights for {', '.join(missing)}")
    out = Path(out)
    return {name: fetch_blob(root, manifest[name]["commit"], manifest[name]["file"], manifest[name]["sha256"],
                             out / manifest[name]["file"], name) for name in names}


def main(argv: list[str] | None = None) -> int:
    from assets.cli import add_out, run_cli

    parser = argparse.ArgumentParser(prog="python -m networks.weights",
                                     description="The trained weights kept in the repository's history.")
    parser.add_argument("--repo", type=Path, default=None,
                        help="the repository (default: the one holding this package)")
    commands = parser.add_subparsers(dest="command", required=True)
    put = commands.add_parser("store", help="commit <name>.pt checkpoints of a folder and list them in the manifest")
    put.add_argument("folder", type=Path, help=f"a folder of {', '.join(n + '.pt' for n in NETWORKS)} (any)")
    put.add_argument("--source", default="", help="where they come from (a run, its data), kept in the manifest")
    get = commands.add_parser("fetch", help="write the stored checkpoints out, checked")
    add_out(get, "folder to write (default %(default)s)", required=False, default="out/weights")
    get.add_argument("--networks", default="", help=f"comma-separated names ({', '.join(NETWORKS)}; default all stored)")
    commands.add_parser("list", help="print the manifest")
    args = parser.parse_args(argv)

    def action() -> None:
        if args.command == "store":
            manifest = store(args.folder, root=args.repo, source=args.source)
            print(f"stored {', '.join(sorted(manifest['weights']))}; HEAD is the merge commit")
        elif args.command == "fetch":
            names = tuple(n.strip() for n in args.networks.split(",") if n.strip()) or None
            for name, path in fetch(args.out, root=args.repo, names=names).items():
                print(f"{name}: {path}")
        else:
            print(json.dumps(read_manifest(repository_root(args.repo))["weights"], indent=2, sort_keys=True))

    return run_cli(action)


if __name__ == "__main__":
    sys.exit(main())
