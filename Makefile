# The README's commands. Each target sets up .venv first if needed (nothing else is required).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
OUT ?= runs/quick
REPORT ?= docs/results/standard/report.html
SHOT ?= docs/report-screenshot.png

.PHONY: run data test lint bench-generate bench-detectors bench-bounds bench-recordings bench-standard \
	screenshot clean

run: $(STAMP)  ## main job: the quick benchmark (8 stages x every detector, ~10 min on 2 cores)
	$(BIN)/railwatch bench --preset quick --out $(OUT)

data: $(STAMP)  ## generate all eight stages (3,000 windows each) and draw Figure 1
	@mkdir -p runs/benchmark
	@for s in 1 2 3 4 5 6 7 8; do \
		$(BIN)/railwatch generate --stage $$s --n 3000 --seed 0 --out runs/benchmark/stage$$s.npz \
			|| exit 1; \
	done
	$(BIN)/railwatch figure stages --out runs/benchmark/stages.png
	@echo "benchmark data and figure in runs/benchmark/"

test: $(STAMP)  ## the whole test suite (slow tests included)
	$(BIN)/python -m pytest

lint: $(STAMP)  ## developer loop: lint and type-check
	$(BIN)/ruff check src tests
	$(BIN)/mypy

bench-generate: $(STAMP)  ## time `railwatch generate` for every stage at n = 100,000
	$(BIN)/python benchmarks/generate_speed.py

bench-detectors: $(STAMP)  ## stage-1 AUC, fit and scoring time of every detector
	$(BIN)/python benchmarks/detectors.py

bench-bounds: $(STAMP)  ## stage 1: a supervised bound per representation, next to its detector
	$(BIN)/python benchmarks/representation_bounds.py

bench-recordings: $(STAMP)  ## detection quality, real-time factor and onboard latency on recordings
	$(BIN)/python benchmarks/recordings.py --work runs/recordings

bench-standard: $(STAMP)  ## the standard benchmark (3 seeds, 3,000 test windows; ~1 h on 2 cores)
	$(BIN)/railwatch bench --preset standard --out runs/standard

screenshot:  ## render REPORT in headless Chromium into SHOT (installs Debian's chromium if missing)
	@command -v chromium >/dev/null || { apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } || \
		{ echo "cannot install chromium: run 'apt-get install chromium' as root"; exit 1; }
	chromium --headless --no-sandbox --disable-gpu --disable-dev-shm-usage --hide-scrollbars \
		--disable-background-networking --no-first-run --window-size=1400,$(or $(HEIGHT),9000) \
		--screenshot=$(abspath $(SHOT)) file://$(abspath $(REPORT))

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev,ray]'
	@touch $@

clean:
	rm -rf $(VENV) runs .pytest_cache .mypy_cache .ruff_cache
