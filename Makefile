# The README's commands. Each target sets up .venv first if needed (nothing else is required).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
OUT ?= runs/benchmark

.PHONY: run test lint bench-generate bench-detectors clean

run: $(STAMP)  ## main job: generate all eight stages and draw Figure 1
	@mkdir -p $(OUT)
	@for s in 1 2 3 4 5 6 7 8; do \
		$(BIN)/railwatch generate --stage $$s --n 3000 --seed 0 --out $(OUT)/stage$$s.npz || exit 1; \
	done
	$(BIN)/railwatch figure stages --out $(OUT)/stages.png
	@echo "benchmark data and figure in $(OUT)/"

test: $(STAMP)  ## the whole test suite (slow tests included)
	$(BIN)/python -m pytest

lint: $(STAMP)  ## developer loop: lint and type-check
	$(BIN)/ruff check src tests
	$(BIN)/mypy

bench-generate: $(STAMP)  ## time `railwatch generate` for every stage at n = 100,000
	$(BIN)/python benchmarks/generate_speed.py

bench-detectors: $(STAMP)  ## stage-1 AUC, fit and scoring time of every detector
	$(BIN)/python benchmarks/detectors.py

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev,ray]'
	@touch $@

clean:
	rm -rf $(VENV) runs .pytest_cache .mypy_cache .ruff_cache
