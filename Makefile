PYTHON ?= python3
ENV ?= animal_walkers
ALGO ?= swat
SEED ?= 0
SEEDS ?= 1
STEPS ?= 10000000
PRESET ?= paper
ARGS ?=
PY ?= 3.12
CPU_DEVICES ?= $(shell nproc)
# JAX sees the CPU's cores as CPU_DEVICES devices, so a run's seeds (or tasks) split over them and each
# core runs its share of the update: 1.11x the fast preset's iteration on 2 cores (BENCHMARKS.md). No effect
# on a GPU, whose devices are JAX's default.
TRAIN_XLA_FLAGS = $(strip $(XLA_FLAGS) --xla_force_host_platform_device_count=$(CPU_DEVICES))

.PHONY: install test test-fast lint format morphologies train resume wheels

install:  ## install swat_jax (editable) with the test and lint tools
	$(PYTHON) -m pip install -e ".[dev]"

test:  ## run the whole test suite (what CI runs)
	$(PYTHON) -m pytest -q -n 2 --dist loadgroup

FAST_TESTS ?= tests/test_encodings.py tests/test_morphologies.py tests/test_mjcf_errors.py tests/test_morphology_cli.py \
	tests/test_observation.py tests/test_replay.py tests/test_limb_buckets.py tests/test_td3_probes.py \
	tests/test_update_schedule.py tests/test_compilation_cache.py tests/test_worker_groups.py \
	tests/test_subprocesses.py tests/test_offline_wheels.py tests/test_variants.py

test-fast:  ## a subset for the development loop (a few minutes on 2 cores): no MJX training runs, no slow tests
	$(PYTHON) -m pytest -q -n 2 --dist loadgroup -m "not slow" $(FAST_TESTS)

lint:  ## static checks
	$(PYTHON) -m ruff check swat_jax tests experiments scripts
	$(PYTHON) -m ruff format --check swat_jax tests experiments scripts

format:  ## apply the formatter and safe lint fixes
	$(PYTHON) -m ruff check --fix swat_jax tests experiments scripts
	$(PYTHON) -m ruff format swat_jax tests experiments scripts

morphologies:  ## regenerate the variant bodies in morphologies/ from the intact ones
	$(PYTHON) -m swat_jax.morphology.generate

train:  ## train: make train ENV=<set or MJCF folder> ALGO= SEED= SEEDS= STEPS= PRESET=paper|fast ARGS="<more flags>"
	XLA_FLAGS="$(TRAIN_XLA_FLAGS)" $(PYTHON) -m swat_jax.train --preset $(PRESET) --env $(ENV) --algo $(ALGO) --seed $(SEED) --seeds $(SEEDS) --steps $(STEPS) $(ARGS)

resume:  ## continue a stopped run with the devices it trained on: make resume RUN=<run directory> [STEPS=<new budget>]
	XLA_FLAGS="$(TRAIN_XLA_FLAGS)" $(PYTHON) -m swat_jax.train --resume $(RUN) $(if $(filter command line,$(origin STEPS)),--steps $(STEPS))

wheels:  ## download into .whl/ the wheels a CUDA JAX image lacks (pins from pyproject.toml), for Python $(PY) on x86-64 Linux
	$(PYTHON) scripts/offline_wheels.py --python-version $(PY) --dest .whl
