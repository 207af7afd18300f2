"""The `networks` package as a user meets it: a flat documented API that imports without torch, and no
script beside the benchmarks that shadows it (its import cycles: tests/test_import_cycles.py)."""

import subprocess
import sys
from pathlib import Path

import networks
from tests.package_api import check_flat_api

PROJECT = Path(__file__).resolve().parents[2]


def test_import_networks_needs_no_torch():
    code = "import sys, networks; print(sorted(m for m in ('torch', 'cv2', 'tqdm') if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_every_public_name_resolves_documented_and_survives_importing_the_modules():
    check_flat_api(networks)
    assert networks.TrainConfig("localizer").task == "localizer"


def test_no_script_beside_the_benchmarks_or_research_shadows_the_package():
    """`python benchmarks/x.py` puts benchmarks/ first on sys.path: a benchmarks/networks.py there would
    be imported for `import networks`."""
    for folder in ("benchmarks", "research"):
        assert not (PROJECT / folder / "networks.py").exists(), folder
