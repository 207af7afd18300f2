# The two commands of the README.  Both create .venv on first use and reinstall when pyproject.toml
# changes; nothing else needs to be installed beforehand but Python 3.11.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DEMO_OUT ?= out/demo

.PHONY: demo test bench clean

demo: $(STAMP)
	$(BIN)/python -m assets.pattern --out $(DEMO_OUT)/pattern
	$(BIN)/python -m assets.garments build shirt --levels 12,4,2 --out $(DEMO_OUT)/shirt
	$(BIN)/python -m assets.motion preview walk --body default --out $(DEMO_OUT)/walk
	$(BIN)/python -m factory.simulate --garment shirt --motion walk --body default --frames 360 --out $(DEMO_OUT)/shirt_walk

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python benchmarks/pattern.py
	$(BIN)/python benchmarks/garments.py
	$(BIN)/python benchmarks/body.py
	$(BIN)/python benchmarks/simulate.py

$(STAMP): pyproject.toml Makefile
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# The CPU build of torch that these machines carry; an unpinned torch would pull GBs of CUDA.
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[all,dev]'
	touch $@

clean:
	rm -rf $(VENV) out .pytest_cache
