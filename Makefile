# Two entry points for a fresh clone: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test bench docs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[test,bench,docs]"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/fwl run --output out/run --points-per-range 300

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadfile  # two processes, a test module each; the engine compiles once (tests/parallel.py)

bench: $(STAMP)
	$(BIN)/python bench/bench_engine.py
	$(BIN)/python bench/bench_read.py
	$(BIN)/python bench/bench_pipeline.py
	$(BIN)/python bench/bench_survey.py
	$(BIN)/python bench/bench_radiometry.py
	$(BIN)/python bench/bench_instrument.py
	$(BIN)/python bench/bench_query.py --compact
	$(BIN)/python bench/bench_small.py
	$(BIN)/python bench/bench_gedi.py

docs: $(STAMP)
	$(BIN)/python docs/screenshot.py
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) out
