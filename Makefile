PYTHON ?= python3

.PHONY: install test lint format morphologies

install:  ## install swat_jax (editable) with the test and lint tools
	$(PYTHON) -m pip install -e ".[dev]"

test:  ## run the whole test suite (what CI runs)
	$(PYTHON) -m pytest -q -n 2

lint:  ## static checks
	$(PYTHON) -m ruff check swat_jax tests experiments
	$(PYTHON) -m ruff format --check swat_jax tests experiments

format:  ## apply the formatter and safe lint fixes
	$(PYTHON) -m ruff check --fix swat_jax tests experiments
	$(PYTHON) -m ruff format swat_jax tests experiments

morphologies:  ## regenerate the variant bodies in morphologies/ from the intact ones
	$(PYTHON) -m swat_jax.morphology.generate
