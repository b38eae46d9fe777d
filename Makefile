# The two commands of the README: `make demo` (the main job) and `make test`.
# Both create the virtual environment and install bayesdoor on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

$(BIN)/bayesdoor: pyproject.toml requirements.lock
	@$(PY) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null || \
		{ echo "error: bayesdoor needs Python 3.11 or newer; $(PY) is $$($(PY) --version 2>&1 || echo missing): run make PY=python3.11 (or newer)"; exit 1; }
	@echo "installing bayesdoor and its dependencies into $(VENV) (first use only, a few minutes)"
	$(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]" -c requirements.lock
	touch $(BIN)/bayesdoor

# the versions of a fresh install of pyproject's floors, as requirements.lock's constraints
lock:
	rm -rf .venv-lock
	$(PY) -m venv .venv-lock
	.venv-lock/bin/python -m pip install --quiet --upgrade pip
	.venv-lock/bin/python -m pip install --quiet -e ".[dev]"
	{ echo "# The versions the results were measured with: the constraints 'make install' installs from."; \
	  echo "# pyproject.toml keeps the floors for library users. Regenerate with 'make lock'."; \
	  .venv-lock/bin/python -m pip freeze --exclude-editable; } > requirements.lock
	rm -rf .venv-lock

.PHONY: install demo test test-long lint bench results docs lock
install: $(BIN)/bayesdoor

demo: install
	$(BIN)/bayesdoor demo --quick --out out/demo --force

test: install
	$(BIN)/python -m pytest -n 2 -q

# the end-to-end tests of a few minutes each, outside the default suite (CI runs them too),
# with XLA's optimisations on (the default suite turns them off to compile faster)
test-long: install
	BAYESDOOR_TEST_XLA_OPT=1 $(BIN)/python -m pytest -n 2 -q -m long

lint: install
	$(BIN)/ruff check bayesdoor tests benchmarks scripts examples docs/api
	$(BIN)/ruff format --check bayesdoor tests benchmarks scripts examples docs/api
	$(BIN)/mypy
	$(BIN)/lint-imports

bench: install
	$(BIN)/python benchmarks/bench_simulate.py

results: install
	$(BIN)/python scripts/make_results.py

docs: install
	$(BIN)/mkdocs build --strict
