# The two commands of the quickstart: `make demo` and `make test`.
# Both bootstrap what they need (libLLVM >= 16, .venv, dependencies) first.
VENV   := .venv
PY     := $(VENV)/bin/python
CLI    := $(VENV)/bin/nirc-bench
DEMO_DIR ?= data/demo

.PHONY: bootstrap demo test test-fast bench reproduce lint docker clean

bootstrap:
	@bash scripts/bootstrap.sh

demo: bootstrap
	$(CLI) render --scene cornell-box --method pt --res 64 --spp 1 --frames 4 --seeds 8 \
		--ref-spp 4096 --out $(DEMO_DIR)

# The store/queue tests also run on a throw-away PostgreSQL server on loopback, and
# the dashboard tests in a headless Chromium: scripts/with_test_services.sh installs
# Debian's postgresql and chromium when missing (as root), starts the server, and stops
# it at the end if it started it.
WITH_SERVICES := bash scripts/with_test_services.sh
# test-fast: the fixed subset listed in tests/fast_tests.txt (marked `fast`), a few
# minutes on 2 cores; it fails naming any product module none of its tests exercised
# (tests/fast_subset.py). `make test` runs them all.
# test: the suite on TEST_WORKERS processes (pytest-xdist), each test file on one process
# (--dist loadfile: a file's module fixtures, its scenes and trained caches, are built
# once). Two on a 2-core machine: much of the suite is single-threaded Python or waits
# on the processes it starts (servers, workers, render processes), and a second process
# fills that time. TEST_WORKERS=0 runs it in this one process.
TEST_WORKERS ?= 2
test: bootstrap
	$(WITH_SERVICES) $(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-fast: bootstrap
	$(WITH_SERVICES) $(PY) -m pytest -q -rfE --fast-subset

bench: bootstrap
	$(PY) -m benchmarks.bench_frame_cost
	$(PY) -m benchmarks.bench_pt
	$(PY) -m benchmarks.bench_cache
	$(PY) -m benchmarks.bench_nirc
	$(PY) -m benchmarks.bench_queries
	$(PY) -m benchmarks.bench_restir
	$(PY) -m benchmarks.bench_di
	$(PY) -m benchmarks.bench_nvc
	$(PY) -m benchmarks.bench_env_cache
	$(PY) -m benchmarks.bench_sweep
	$(PY) -m benchmarks.bench_pareto
	$(PY) -m benchmarks.bench_service

# Every registered figure of the papers at its --quick budget, one after another, then
# one summary of the verdicts and of each figure's wall and CPU time; fails if any
# figure failed (docs/reproduce.md). Its goal is an hour on 2 cores in all (measured: 17 min
# quiet; a total over it is printed, not a failure): not part of `make test` or CI.
reproduce: bootstrap
	$(CLI) reproduce --all --quick

# Every image of docker/Dockerfile (needs a Docker engine; BASE_IMAGE=... to override).
DOCKER_TARGETS := cli service scheduler worker worker-gpu
docker:
	for target in $(DOCKER_TARGETS); do \
		docker build -f docker/Dockerfile --target $$target \
			$${BASE_IMAGE:+--build-arg BASE_IMAGE=$$BASE_IMAGE} \
			--build-arg GIT_COMMIT=$$(git rev-parse HEAD) -t nirc-bench:$$target . || exit 1; \
	done

lint: bootstrap
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) .pytest_cache data/demo
