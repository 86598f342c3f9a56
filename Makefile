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
REPORT ?= docs/results/standard/report.html
SHOT ?= docs/report-screenshot.png

.PHONY: run data test test-latest lock lint bench-generate bench-detectors bench-bounds bench-recordings bench-recordings-nuisance bench-track-map bench-track-map-loss bench-track-map-fusion bench-track-map-frame bench-track-map-sides bench-physics bench-matched-filter-ridge bench-reliability bench-residual-glr bench-context-glr bench-context-glr-speed bench-context-glr-swap \
	bench-standard screenshot clean

run: $(STAMP)  ## main job: the quick benchmark (8 stages x every detector, 12.7 min on 2 cores from a fresh clone)
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

bench-recordings-nuisance: $(STAMP)  ## train on two runs, detect on a third: stage-5/8-like runs, loud stretches
	$(BIN)/python benchmarks/recordings_nuisance.py --work runs/recordings-nuisance

bench-track-map: $(STAMP)  ## the track map of 10-km tracks against 1, 2, 5, 10 passes; scan throughput (~40 min)
	$(BIN)/python benchmarks/track_map.py --work runs/bench-track-map

bench-track-map-loss: $(STAMP)  ## where the track map loses defects: oracle, per pass, alignment (~30 min, after bench-track-map)
	$(BIN)/python benchmarks/track_map_loss.py --work runs/bench-track-map

bench-track-map-fusion: $(STAMP)  ## what each rule of the fused map adds, on development tracks (~15 min, after bench-track-map)
	$(BIN)/python benchmarks/track_map_fusion.py --work runs/bench-track-map

bench-track-map-frame: $(STAMP)  ## the fused map's frame and the check of the alignment's moves, 8 development tracks (~30 min, after bench-track-map)
	$(BIN)/python benchmarks/track_map_frame.py --work runs/bench-track-map

bench-track-map-sides: $(STAMP)  ## what the fused map sums over the passes: the sides of the vehicle, 8 development tracks (~15 min, after bench-track-map-frame and track_map_wheel.py)
	$(BIN)/python benchmarks/track_map_sides.py --work runs/bench-track-map

bench-physics: $(STAMP)  ## physics tracks at field scale: one pass, the map, POD, beside the oracle (~40 min)
	$(BIN)/python benchmarks/physics.py --work runs/physics

bench-matched-filter-ridge: $(STAMP)  ## the matched filter's ridge on benchmark windows and on windows made unlike ours (~5 min)
	$(BIN)/python benchmarks/matched_filter_ridge.py

bench-reliability: $(STAMP)  ## the fault and fuzz tests, counted into docs/results/reliability.md
	$(BIN)/python benchmarks/reliability.py

bench-residual-glr: $(STAMP)  ## stages 1-8: GLR scoring of the true and of cnn-ae's residual
	$(BIN)/python benchmarks/residual_glr.py

bench-context-glr: $(STAMP)  ## stages 1,4,5,7,8: context-glr's prediction error and its supervised bound
	$(BIN)/python benchmarks/context_glr.py

bench-context-glr-swap: $(STAMP)  ## stages 5, 7: context-glr's prediction and noise scale swapped for the truth (~3 min)
	$(BIN)/python benchmarks/context_glr_swap.py 5,7

bench-context-glr-speed: $(STAMP)  ## context-glr's width against AUC, fit, scoring and ONNX time (~15 min)
	$(BIN)/python benchmarks/context_glr_speed.py

bench-standard: $(STAMP)  ## the standard benchmark (3 seeds, 3,000 test windows; ~1 h on 2 cores)
	$(BIN)/railwatch bench --preset standard --out runs/standard

screenshot:  ## render REPORT in headless Chromium into SHOT (installs Debian's chromium if missing)
	@command -v chromium >/dev/null || { apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } || \
		{ echo "cannot install chromium: run 'apt-get install chromium' as root"; exit 1; }
	chromium --headless --no-sandbox --disable-gpu --disable-dev-shm-usage --hide-scrollbars \
		--disable-background-networking --no-first-run --window-size=1400,$(or $(HEIGHT),9000) \
		--screenshot=$(abspath $(SHOT)) file://$(abspath $(REPORT))

# The set-up: exactly the versions in requirements.lock (pip and setuptools included), then
# railwatch itself without resolving anything again.
$(STAMP): pyproject.toml $(LOCK)
	@$(PYTHON) -c 'import sys; v = sys.version_info[:2]; v == (3, 11) or print( \
		f"note: $(LOCK) was compiled for Python 3.11, this is {v[0]}.{v[1]}: if the set-up " \
		"fails, run make lock first")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet -r $(LOCK)
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	$(BIN)/python -m pip check
	@touch $@

clean:
	rm -rf $(VENV) $(LATEST) runs .pytest_cache .mypy_cache .ruff_cache
