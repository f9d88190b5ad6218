# The two commands of the README (make run, make test). Each creates .venv and installs the project on first use.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
# pytest-xdist workers: XLA compiles are single-threaded, so one per core
JOBS   ?= 2
STAMP  := $(VENV)/.installed-stamp
BENCH_STAMP := $(VENV)/.bench-stamp
DOCS_STAMP  := $(VENV)/.docs-stamp

.PHONY: run test test-xla-defaults bench docs notebooks clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,peers]"
	touch $(STAMP)

## run: the main job (writes its table/plot/numbers under out/)
run: $(STAMP)
	$(PY) -m particlesim.cli main

## test: the whole test suite (float64), one worker per core, each test module kept on one worker
test: $(STAMP)
	$(PY) -m pytest -q -n $(JOBS) --dist loadscope $(PYTEST_ARGS)

## test-xla-defaults: the reference and round-off-sensitive tests again with the tests' own jits on XLA's default
## CPU emitters (as a user's own jax.jit), not the faster-compiling ones the suite uses (tests/conftest.py)
XLA_DEFAULTS_TESTS ?= tests/mechanism/test_redundant.py tests/mechanism/test_nikravesh.py \
	tests/tree/test_pinocchio.py tests/tree/test_dart.py tests/twins/test_krang_twin.py
# (not MJX's own float64 run, nor the error-message test: nothing of ours there depends on the emitters)
XLA_DEFAULTS_SKIP ?= not mjx_float64 and not exhausted_step_budget
test-xla-defaults: $(STAMP)
	PARTICLESIM_TEST_XLA_DEFAULTS=1 $(PY) -m pytest -q -n $(JOBS) --dist loadscope $(XLA_DEFAULTS_TESTS) \
		-k "$(XLA_DEFAULTS_SKIP)" $(PYTEST_ARGS)

$(BENCH_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e ".[test,bench]"
	touch $(BENCH_STAMP)

## bench: rerun the benchmarks, rewrite benchmarks/results/ and the tables of benchmarks/README.md
bench: $(BENCH_STAMP)
	$(PY) -m benchmarks.run_all

$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e ".[docs]"
	touch $(DOCS_STAMP)

## docs: the documentation site in site/ (the guides, the notebooks with their saved outputs, the API reference from
## the docstrings); any warning fails the build. (Material for MkDocs' banner about its successor is switched off.)
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict

## notebooks: rebuild the notebooks from notebooks/build_*.py and execute them in place, saving their outputs
notebooks: $(STAMP)
	$(PY) notebooks/run.py

clean:
	rm -rf $(VENV) out site .pytest_cache
