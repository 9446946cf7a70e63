# Two set-up-and-go commands: `make demo` and `make test`. Both create .venv when missing.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

export RAY_USAGE_STATS_ENABLED := 0
export HF_HUB_OFFLINE := 1
export TRANSFORMERS_OFFLINE := 1

.PHONY: install test test-fast lint demo browser docs-screenshot clean

install: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	PYTHONWARNINGS=ignore $(PY) -m pip install -q -c constraints.txt torch==2.13.0
	PYTHONWARNINGS=ignore $(PY) -m pip install -q -c constraints.txt -e '.[dev]'
	touch $(STAMP)

lint: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

test: lint
	$(PY) -m pytest -q

# The inner loop: the suite without the slow end-to-end cases (cluster, kill, demo).
test-fast: install
	$(PY) -m pytest -q -m "not slow"

demo: install
	$(VENV)/bin/motionaug demo

# Opt-in: the system Chromium for tests/test_viewer_browser.py (Debian's package, as root; never a browser download).
# `make install` and `make demo` never need it; without it the browser tests skip (they fail under CI=true).
browser:
	@if command -v chromium >/dev/null 2>&1; then echo "chromium: $$(command -v chromium)"; \
	elif [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq chromium; \
	else echo "run as root: apt-get install -y chromium (or set MOTIONAUG_CHROMIUM=/path/to/chromium)"; exit 1; fi

# The README's viewer picture, from a run (default: the demo's); needs Chromium (make browser).
RUN ?= demo-out/run
docs-screenshot: install
	$(PY) docs/viewer_screenshot.py $(RUN) --out docs/viewer.png

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info
