# The two commands of the README.  Both create .venv on first use and reinstall when pyproject.toml
# changes; nothing else needs to be installed beforehand but Python 3.11.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO_OUT ?= out/demo

.PHONY: demo test bench clean blender

demo: $(STAMP)
	$(BIN)/python -m assets.pattern --out $(DEMO_OUT)/pattern
	$(BIN)/python -m assets.garments build shirt --levels 12,4,2 --out $(DEMO_OUT)/shirt
	$(BIN)/python -m assets.motion preview walk --body default --out $(DEMO_OUT)/walk
	$(BIN)/python -m factory.simulate --garment shirt --motion walk --body default --frames 360 --out $(DEMO_OUT)/shirt_walk
	$(BIN)/python -m factory.dataset build --garment shirt --motions walk --frames 2 --variations 5 \
		--resolution 256 --samples 16 --reuse-simulation walk=$(DEMO_OUT)/shirt_walk --out $(DEMO_OUT)/dataset
	$(BIN)/python -m factory.dataset capture --garment shirt --motion walk --frames 3 --cameras 4 \
		--resolution 640x360 --samples 16 --reuse-simulation $(DEMO_OUT)/shirt_walk --out $(DEMO_OUT)/capture
# the shipped networks, written from the repository's history (kept when their SHA-256 matches)
	$(BIN)/python -m networks.weights fetch --out $(DEMO_OUT)/weights
	$(BIN)/python -m reconstruction run --views $(DEMO_OUT)/capture --template $(DEMO_OUT)/capture/template.npz \
		--out $(DEMO_OUT)/reconstruction --localizer $(DEMO_OUT)/weights/localizer.pt \
		--recognizer $(DEMO_OUT)/weights/recognizer.pt --crosspoints $(DEMO_OUT)/weights/crosspoints.pt \
		--levels 12 --evaluate
	$(MAKE) addon

# The Blender add-on as one zip (extension and legacy add-on): out/addon/clothcapture-<version>.zip.
# Standard library only, so any Python 3.11 builds it.
.PHONY: addon
addon:
	$(PYTHON) -m blender_addon.package --out out/addon

# Two workers (pytest-xdist), each test file whole on one so that its module fixtures are made once; the
# session's shirt walk and capture are made once for both (tests/conftest.py).  One process keeps one
# of the two cores busy (2,400 s of CPU, 2,347 s in CI); the second worker takes the other.  Here and
# not in pytest's addopts: benchmarks/hostile.py runs the suite in its own process with a plugin.
test: $(STAMP) blender
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

# Debian's Blender 3.4 for the `blender -b -P factory/render.py` tests (the bpy module is in the venv)
blender:
	@command -v blender >/dev/null 2>&1 || { apt-get update -qq && apt-get install -y -qq --no-install-recommends blender >/dev/null; }

bench: $(STAMP)
	$(BIN)/python benchmarks/pattern.py
	$(BIN)/python benchmarks/garments.py
	$(BIN)/python benchmarks/body.py
	$(BIN)/python benchmarks/simulate.py
	$(BIN)/python benchmarks/render.py
	$(BIN)/python benchmarks/reconstruction_capture.py --refine-frames 12:120,4:6,2:3
	$(BIN)/python benchmarks/hostile.py

$(STAMP): pyproject.toml Makefile
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# The CPU build of torch that these machines carry; an unpinned torch would pull GBs of CUDA.
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[all,dev]'
	touch $@

clean:
	rm -rf $(VENV) out .pytest_cache
