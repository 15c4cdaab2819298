# The README's two commands: `make demo` and `make test`. Each creates .venv by itself.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
BINTRACK := $(VENV)/bin/bintrack
STAMP  := $(VENV)/.installed

.PHONY: demo test datasets clean bench bench-multi

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BINTRACK) demo

test: $(STAMP)
	$(PY) -m pytest -q

# Our MCMCDA against Stone Soup's GNN and JPDA (issue 6): needs the optional extra `bench`
# (Stone Soup), which only this target installs. 3–6 min on 2 cores; `make bench BENCH_ARGS=--quick`
# tries one Stone Soup setting instead of tuning (about 1 min).
BENCH_STAMP := $(VENV)/.installed-bench
BENCH_ARGS ?=

$(BENCH_STAMP): $(STAMP) pyproject.toml
	$(PY) -m pip install --quiet -e '.[test,bench]'
	touch $(BENCH_STAMP)

bench: $(BENCH_STAMP)
	$(PY) benchmarks/mcmcda_vs_stonesoup.py $(BENCH_ARGS)

# Issue 21: our MCMCDA against Stone Soup tuned on half of a suite of simulated grids and scored
# on the other half (benchmarks/multi_target.py; `BENCH_ARGS=--quick` for a smaller run).
bench-multi: $(BENCH_STAMP)
	nice -n 10 $(PY) benchmarks/multi_target.py $(BENCH_ARGS)

# Remakes every shipped dataset byte for byte (seeds fixed).
datasets: $(STAMP)
	$(BINTRACK) simulate darpa-grid --people 1 --seed 1 --out datasets/darpa-grid-1
	$(BINTRACK) simulate darpa-grid --people 2 --seed 2 --out datasets/darpa-grid-2
	$(BINTRACK) simulate darpa-grid --people 3 --seed 3 --out datasets/darpa-grid-3
	$(BINTRACK) simulate laser-testbed --seed 1 --out datasets/laser-testbed

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis out
