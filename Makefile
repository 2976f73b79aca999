# shaftgauge: every target installs what it needs first (apt packages, .venv), idempotently.
SHELL := /bin/bash
VENV  := .venv
PY    := $(VENV)/bin/python
STAMP := $(VENV)/.shaftgauge-installed

# What make runs writes its bytecode, PYTHONDONTWRITEBYTECODE or not (a developer's shell or
# a CI runner may set it): the suites start hundreds of Python processes, and without it each
# one compiles all it imports anew (a service's start: 4.5 s of CPU, 2.8 with it) and each
# pytest process rewrites every test module's asserts (10 s, 5 with it).
export PYTHONDONTWRITEBYTECODE :=

.PHONY: setup run test speed check docs bench soak lint clean linuxcnc-demo lock wheel wheel-test

setup: $(STAMP)

$(STAMP): pyproject.toml deploy/bootstrap.sh deploy/requirements-test.lock
	bash deploy/bootstrap.sh

## make run: the service on its embedded default (simulated GigE camera and PLC on loopback).
run: setup docs
	$(PY) -m service.measure.compiled
	$(VENV)/bin/shaftgauge serve

## make linuxcnc-demo: the gauge with LinuxCNC's simulated lathe taking its offsets (pull
## handshake, deploy/linuxcnc/); Ctrl-C ends it.
linuxcnc-demo: setup
	$(PY) -m service.measure.compiled
	bash deploy/linuxcnc/demo.sh

## make test: lint, then the whole suite (short fault runs included; long soak runs and the
## speed guard left out) on six workers: many tests wait on a service, LinuxCNC or a lathe
## they started (six, since LinuxCNC's group holds one worker for its 200 s of mostly
## waiting; see the CHANGELOG). No test times anything: it passes on any two-core machine,
## loaded or not (a slower one takes longer). The files of a test or two that mostly wait (the
## short soak, the lathe loop, a backup, the plant) go first, then the files of a minute or
## more (tests/conftest.py EARLY, LONG; --no-loadscope-reorder keeps that order): last, they
## left the phase's end on half the machine. Beside each other, the workers and the services they start each use one thread
## for BLAS, OpenCV and numba: more threads than cores only wait for each other.
ONE_THREAD := OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 OPENCV_FOR_THREADS_NUM=1
test: setup docs
	$(VENV)/bin/ruff check .
	$(PY) -m service.measure.compiled
	$(ONE_THREAD) $(PY) -m pytest -m "not slow and not wheel and not timed" -q -n 6 \
		--dist loadgroup --no-loadscope-reorder --durations=20

## make speed: the speed guard, alone (the core's and the service's speed ratios against the
## committed baseline, bench-results/guard.json): before closing a change to measure/,
## runtime/ or drivers/sim/.
speed: setup
	$(PY) -m service.measure.compiled
	$(PY) -m pytest -m timed -q

## make check: the fast layer for a developer's loop (lint, unit and property tests, on both
## cores): under two minutes.
check: setup
	$(VENV)/bin/ruff check .
	$(PY) -m service.measure.compiled
	$(PY) -m pytest -m "not slow and not wheel and not timed" -q -n 2 tests/unit tests/fuzz

## make lock: renew the lock files from pyproject.toml (pip-tools, in a venv of its own):
## deploy/requirements-test.lock (the service and its test tools: development and CI) and
## deploy/requirements.lock (the service alone, at the same versions: installations).
LOCK_OPTS := --quiet --generate-hashes --allow-unsafe --strip-extras --no-emit-index-url \
	--no-emit-find-links --no-header --upgrade
lock:
	python3 -m venv build/lock-venv
	build/lock-venv/bin/pip install -q 'pip-tools>=7.4,<8'
	build/lock-venv/bin/pip-compile $(LOCK_OPTS) --extra test -o deploy/requirements-test.lock pyproject.toml
	build/lock-venv/bin/pip-compile $(LOCK_OPTS) -c deploy/requirements-test.lock -o deploy/requirements.lock pyproject.toml

## make wheel: the installable package in build/dist (the manual and the commit it was built
## from inside it).
wheel: setup docs
	git rev-parse --short=12 HEAD > service/BUILD_COMMIT
	$(PY) -m pip wheel -q --no-deps -w build/dist .
	rm -f service/BUILD_COMMIT

## make wheel-test: the wheel built from this tree, installed in a clean venv from
## deploy/requirements.lock, serves the embedded default with its dashboard (CI runs it).
wheel-test: setup docs
	$(PY) -m pytest -m wheel -q tests/release

## make docs: the manual (docs/) built into service/web/manual, served at /ui/manual/; a broken
## link fails the build.
docs: setup
	$(VENV)/bin/mkdocs build --quiet

## make bench: accuracy and speed figures; results land in bench-results/ (with the machine,
## the commit and the date), the speed guard's baseline among them, and the manual's figures
## are rendered from them (tests.bench.figures): commit them with the change. The held-out
## sets are scored by hand at the end of a piece of work (robustness, rig_range and
## turning_service with --held-out); their committed results are rendered too.
bench: setup
	$(PY) -m service.measure.compiled
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 $(PY) -m tests.bench.core_throughput
	$(PY) -m tests.bench.paper_comparison
	$(PY) -m tests.bench.beyond_paper
	$(PY) -m tests.bench.principal_point
	$(PY) -m tests.bench.robustness
	$(PY) -m tests.bench.rig_range
	$(PY) -m tests.bench.turning_service
	$(PY) -m tests.bench.camera_throughput
	$(PY) -m tests.bench.service_throughput --seconds 60 --fps 100 --roi on --embedded \
		--json bench-results/service_throughput_embedded.json
	$(PY) -m tests.bench.service_throughput --seconds 60 --fps 100 \
		--json bench-results/service_throughput_100fps.json
	$(PY) -m tests.bench.service_throughput --seconds 30 --fps 200 --roi on \
		--json bench-results/service_throughput_200fps.json
	$(PY) -m tests.bench.plant_publish
	$(PY) -m tests.bench.closed_loop
	$(PY) -m tests.bench.whole_part
	$(PY) -m tests.bench.whole_part --tight-bound
	$(PY) -m tests.bench.whole_part --taper 15
	$(PY) -m tests.bench.whole_part --taper 15 --entries
	$(PY) -m tests.bench.whole_part --taper 15 --entries --skip 0.3
	$(PY) -m tests.bench.guard --runs 3 --write
	$(PY) -m tests.bench.figures
	@git status --short bench-results docs

## make soak: the long soak and fault runs (an hour; SHAFTGAUGE_SOAK_S=600 for ten minutes).
soak: setup
	$(PY) -m service.measure.compiled
	$(PY) -m pytest -m slow -q

lint: setup
	$(VENV)/bin/ruff check .

clean:
	rm -rf $(VENV) bench-results test-artifacts .pytest_cache .ruff_cache service/web/manual
