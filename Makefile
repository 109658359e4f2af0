PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# mkdocs-material and a plugin print an end-of-life banner on every build; the pins in constraints.txt hold.
DOCS_ENV := NO_MKDOCS_2_WARNING=1 DISABLE_MKDOCS_2_WARNING=true

.PHONY: test lint typecheck demo docs clean

# The venv is rebuilt whenever pyproject.toml or constraints.txt changes. constraints.txt pins every package to the
# versions the figures in the notes were measured with, so an install is repeatable (a diagnosis can still differ
# between machines in its floating-point rounding: 0627 after, ninth stop's note).
$(VENV): pyproject.toml constraints.txt
	@echo "creating $(VENV): cellcal and every package at the version constraints.txt pins (about 2 min, quiet)"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c constraints.txt -e '.[dev]'
	touch $(VENV)

# On every core (pytest-xdist): whole modules per worker, the longest first (tests/conftest.py says why).
# Bytecode is cached (__pycache__, ignored by git) even where PYTHONDONTWRITEBYTECODE is set: otherwise each worker
# re-rewrites the assertions of every test module at collection (7 s of a core per worker) and every cellcal
# process the tests start compiles the package again.
# The docs site is built first, strictly (a broken link, a page left out of the navigation or a module the API pages
# cannot read fails the tests), into a temporary folder that is removed afterwards; `make docs` keeps it in site/.
# The type check (mypy, ~20 s of one core from a cold cache, ~3 s warm) runs beside the docs build, one core each.
test: lint
	site=$$(mktemp -d) && trap 'rm -rf "$$site"' EXIT && \
	  { $(DOCS_ENV) $(BIN)/mkdocs build --strict --site-dir "$$site" & docs=$$!; } && \
	  $(BIN)/mypy && wait $$docs
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n auto --dist loadscope --no-loadscope-reorder

# The lint before the tests, about 1 s each: ruff (the rules in pyproject.toml) and the import contracts
# (import-linter, [tool.importlinter]: the product's layers, no circle, calibration math only).
lint: $(VENV)
	$(BIN)/ruff check --no-cache .
	$(BIN)/lint-imports --no-cache

# Types alone (pyproject.toml: strict on calibration/ and drivers/, every def typed on app/ and cell_config/); also
# part of `make test`.
typecheck: $(VENV)
	$(BIN)/mypy

docs: $(VENV)
	$(DOCS_ENV) $(BIN)/mkdocs build --strict --site-dir site

demo: $(VENV)
	$(BIN)/cellcal demo --out demo_out

clean:
	rm -rf $(VENV) demo_out site .pytest_cache .mypy_cache .ruff_cache
