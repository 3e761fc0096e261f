# bayestouch — the two commands of the README (make demo, make test) plus bench and lint.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

export OMP_NUM_THREADS ?= 1
export XLA_FLAGS ?= --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1

.PHONY: demo test test-fast bench lint install clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[dev]"
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/bayestouch demo --out out/demo

# two workers (the CI machine has 2 cores; the suite is single-threaded per test), whole files per worker so
# module fixtures are built once; a worker that crashes (a segfault) fails the run at once, naming its test, instead
# of being replaced (xdist's loadfile scheduling can then wait forever: pytest-xdist issue 784)
XDIST = -n 2 --dist loadfile --max-worker-restart=0

test: $(STAMP)
	$(PY) -m pytest -q $(XDIST) --durations=15

test-fast: $(STAMP)
	$(PY) -m pytest -q $(XDIST) -m "not slow"

bench: $(STAMP)
	$(PY) -m benchmarks

lint: $(STAMP)
	$(VENV)/bin/ruff check bayestouch tests benchmarks data
	$(VENV)/bin/ruff format --check bayestouch tests benchmarks data

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache
