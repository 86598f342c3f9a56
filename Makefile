# The README's commands. Each target sets up .venv first if needed (nothing else is required).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
LOCK := requirements.lock
LATEST ?= .venv-latest
# How requirements.lock is made from pyproject.toml's ranges (torch held by constraints.txt).
COMPILE := $(BIN)/pip-compile --quiet --extra dev --extra ray --all-build-deps --allow-unsafe \
	--strip-extras --no-emit-index-url --no-emit-find-links -c constraints.txt -o $(LOCK)
OUT ?= runs/quick
REPORT ?= docs/results/paper/standard/report.html
SHOT ?= docs/report-screenshot.png

.PHONY: run data test test-latest lock lint benchmarks bench-standard screenshot chromium clean

run: $(STAMP)  ## main job: the quick benchmark (8 stages x every detector, 9.5-12.9 min on 2 cores from a fresh clone)
	$(BIN)/railwatch bench --preset quick --out $(OUT)

data: $(STAMP)  ## generate all eight stages (3,000 windows each) and draw Figure 1
	@mkdir -p runs/benchmark
	@for s in 1 2 3 4 5 6 7 8; do \
		$(BIN)/railwatch generate --stage $$s --n 3000 --seed 0 --out runs/benchmark/stage$$s.npz \
			|| exit 1; \
	done
	$(BIN)/railwatch figure stages --out runs/benchmark/stages.png
	@echo "benchmark data and figure in runs/benchmark/"

test: $(STAMP) chromium  ## the whole test suite (slow tests included)
	$(BIN)/python -m pytest

test-latest:  ## the suite against the newest releases pyproject.toml allows (in $(LATEST), not the lock)
	rm -rf $(LATEST)
	$(PYTHON) -m venv $(LATEST)
	$(LATEST)/bin/python -m pip install --quiet --upgrade pip
	$(LATEST)/bin/python -m pip install --quiet -c constraints.txt -e '.[dev,ray]'
	$(LATEST)/bin/python tools/lock_drift.py $(LOCK)
	$(LATEST)/bin/python -m pytest

lock: $(STAMP)  ## regenerate requirements.lock with the newest releases (then run make test)
	$(COMPILE) --upgrade pyproject.toml
	@# torch stays a public version: this machine's pip picks its local CPU wheel (2.13.0+cpu),
	@# elsewhere pip takes the same release from PyPI.
	sed -i 's/^torch==\([0-9.]*\)+cpu$$/torch==\1/' $(LOCK)
	@echo "wrote $(LOCK): commit it with the test run that passed on it"

lint: $(STAMP)  ## developer loop: lint and type-check
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy

benchmarks:  ## list the research benchmarks: what each measures, its page, its time, what it needs first
	@$(BIN)/python -m benchmarks

bench-%: $(STAMP)  ## run one: make bench-physics = python -m benchmarks physics (ARGS='...': its options)
	$(BIN)/python -m benchmarks $(subst -,_,$*) $(ARGS)

bench-standard: $(STAMP)  ## the standard benchmark (3 seeds, 3,000 test windows; ~2 h on 2 cores, resumable)
	$(BIN)/railwatch bench --preset standard --out runs/standard

chromium:  ## Debian's chromium, if missing: the browser the track-map report's test drives
	@command -v chromium >/dev/null || { echo "installing Debian's chromium (apt-get) ..."; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium \
		>/dev/null; } || { echo "cannot install chromium: run 'apt-get install chromium' as \
		root (without it the report's browser test is skipped, and fails under CI)"; }

screenshot: chromium  ## render REPORT in headless Chromium into SHOT
	@command -v chromium >/dev/null || exit 1
	chromium --headless --no-sandbox --disable-gpu --disable-dev-shm-usage --hide-scrollbars \
		--disable-background-networking --no-first-run --window-size=1400,$(or $(HEIGHT),9000) \
		--screenshot=$(abspath $(SHOT)) file://$(abspath $(REPORT))

# The set-up: exactly the versions in requirements.lock (pip and setuptools included), then
# railwatch itself without resolving anything again. --no-compile: Python compiles the modules a
# run imports when it first imports them (measured: the install 62 -> 30 s, the first import of
# torch, scipy, sklearn, pandas, matplotlib, pyarrow, onnxruntime 3 -> 8 s).
$(STAMP): pyproject.toml $(LOCK)
	@$(PYTHON) -c 'import sys; v = sys.version_info[:2]; v == (3, 11) or print( \
		f"note: $(LOCK) was compiled for Python 3.11, this is {v[0]}.{v[1]}: if the set-up " \
		"fails, run make lock first")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --no-compile -r $(LOCK)
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	$(BIN)/python -m pip check
	@touch $@

clean:
	rm -rf $(VENV) $(LATEST) runs .pytest_cache .mypy_cache .ruff_cache
