# One-command set-up and entry points. Every target creates the virtual environment on first use.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: install redis up demo test test-all test-fast lint typecheck unit bench clean

# Not quiet: the install takes minutes on a fresh machine, and pip's lines show that it is moving.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install -e '.[services,dev,peers]'
	touch $@

install: $(VENV)/.installed

## redis-server from Debian's packages if missing: the main job and the control plane's tests run a real Redis
redis:
	@command -v redis-server >/dev/null || { SUDO=$$([ "$$(id -u)" = 0 ] || echo sudo); \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq redis-server; }

## Main job: the whole service on this machine (local Redis, level server, Ray actors + learner, evaluator)
## training the default preset until done or Ctrl-C.
up: install redis
# `cec up`, run by apps/make_up.py so that a Ctrl-C reaches it alone from its first line, not make ("make: ***
# [up] Interrupt"); it exits 130 after a clean Ctrl-C (checkpointed, everything stopped): that is success
# here, not make's "Error 130"; CEC_UP_VIA makes its resume hint read `make up ARGS=--resume`.
	CEC_UP_VIA=make $(BIN)/python -m apps.make_up $(ARGS) || [ $$? -eq 130 ]

## Random agents in every classic kitchen, side by side, written to out/demo.gif
demo: install
	$(BIN)/cec demo --out out/demo.gif

## Lint, type checks and the whole test suite (unit + JaxMARL parity)
# Every layer runs on every core (each worker has its own Redis and JAX cache; servers bind free ports),
# except that the end-to-end tests, whole stacks of Ray processes timing their recoveries, run one at a
# time on one worker (their xdist group, tests/conftest.py), listed first so that they start first.
# The three that host Ray's driver run each in a child pytest of its own process group (tests/own_process.py),
# so that a crash there fails that test instead of taking down a worker and its group.
# `make test` is the CI gate: it leaves out the heavy tier (tests/heavy_tier.txt), which `make test-all` adds.
# A worker that dies in native code (JAX once aborted reading its compilation cache) ends the run at once,
# naming the test: xdist 3.8 replaces a crashed worker under --dist loadgroup and can then wait forever
# (pytest-xdist issues 1323, 1327, 1378), which ran the CI into its time limit.
TEST_WORKERS ?= auto
SUITE = $(BIN)/python -m pytest -q --durations=25 -n $(TEST_WORKERS) --dist loadgroup --max-worker-restart=0 \
	tests/e2e tests/unit tests/parity tests/learning tests/services
test: lint typecheck redis
	$(SUITE) -m "not heavy"

test-all: lint typecheck redis
	$(SUITE)

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports  # the layer contract in pyproject.toml: cec <- services <- apps
	$(BIN)/python scripts/history_weight.py  # no file version over 1 MiB since the round's base (DESIGN rule 17)

typecheck: install
	$(BIN)/mypy

unit: install
	$(BIN)/python -m pytest -q tests/unit

## Everyday loop: the library's unit tests without the slow ones, JAX's compiled calls kept in .cache/jax
test-fast: install
	CEC_TEST_JAX_CACHE=.cache/jax $(BIN)/python -m pytest -q -n $(TEST_WORKERS) tests/unit -m "not slow"

## Env throughput vs JaxMARL (N = 256, 1024, 4096); results land in benchmarks/results/
bench: install
	$(BIN)/python benchmarks/env_throughput.py

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache .cache
