PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench browser clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV) || python3 -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

# warm-up compiles the Numba kernels once (minutes on a fresh machine, then cached; a second
# make demo finds them compiled and goes straight on).
demo: $(STAMP)
	$(BIN)/quatmotion warm-up
	$(BIN)/quatmotion demo --force $(DEMO_ARGS)

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -n 2 -q

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

# What the browser tests need: Playwright (dev extras) and Debian's chromium (apt-get if missing).
browser: $(STAMP)
	tools/install-browser

bench: $(STAMP)
	$(BIN)/quatmotion bench io --out bench-io.json --force

clean:
	rm -rf $(VENV) build *.egg-info
