PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench browser fuzz clean

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

# A baseline x86-64 processor: Numba's generic target, NumPy's baseline loops, OpenBLAS's
# oldest kernels (every name NumPy has used for its SIMD levels; unknown ones are ignored).
BASELINE_CPU := NUMBA_CPU_NAME=generic NUMBA_CACHE_DIR=$(CURDIR)/$(VENV)/numba-generic \
	NPY_DISABLE_CPU_FEATURES="X86_V3 X86_V4 AVX512_ICL AVX512_SPR AVX512_SKX AVX512F AVX2 FMA3" \
	OPENBLAS_CORETYPE=Prescott

# The tests that compare the paths to one answer run twice: on this processor, then as on a
# baseline one (results must not depend on the vector width).
test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -n 2 -q
	$(BASELINE_CPU) $(BIN)/python -m pytest -q -m same_answer -p no:randomly

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

# What the browser tests need: Playwright (dev extras) and Debian's chromium (apt-get if missing).
browser: $(STAMP)
	tools/install-browser

# The readers fuzzed for longer than make test does: FUZZ_SECONDS per reader (a finding is kept
# in tests/fuzz/regressions/READER/, which the suite re-reads; exit 1 if anything was found).
# Coverage-guided by atheris (the fuzz extra) where it installs, else the seeded random engine.
FUZZ_SECONDS ?= 600
fuzz: $(STAMP)
	$(BIN)/python -m pip install --quiet -e ".[dev,fuzz]" || echo "atheris not installed: fuzzing without coverage"
	$(BIN)/python tests/fuzz/run.py --seconds $(FUZZ_SECONDS) --jobs 2 $(FUZZ_ARGS)

bench: $(STAMP)
	$(BIN)/quatmotion bench io --out bench-io.json --force

clean:
	rm -rf $(VENV) build *.egg-info
