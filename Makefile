PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: test demo clean

# The venv is rebuilt whenever pyproject.toml changes.
$(VENV): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(VENV)

test: $(VENV)
	$(BIN)/python -m pytest -q

demo: $(VENV)
	$(BIN)/cellcal demo --out demo_out

clean:
	rm -rf $(VENV) demo_out .pytest_cache
