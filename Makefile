# The two commands: `make run` (console on the simulator) and `make test` (the whole suite).
# Each creates .venv when missing and keeps it in step with pyproject.toml.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
HOST   ?= 127.0.0.1
PORT   ?= 8000
ARGS   ?=

.PHONY: run test bench lint node-deps clean

$(VENV)/.installed-run: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[speech,captioner]'
	touch $@

$(VENV)/.installed-test: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(VENV)/.installed-run $@

tests/node/node_modules/.installed: tests/node/package.json tests/node/package-lock.json
	cd tests/node && npm ci --no-audit --no-fund --loglevel=error
	touch $@

node-deps: tests/node/node_modules/.installed

run: $(VENV)/.installed-run
	$(VENV)/bin/uav-console serve --host $(HOST) --port $(PORT) $(ARGS)

# The whole suite is two pytest runs: every file but the browser tests and the tests marked
# `serial` in two worker processes, one test file per worker at a time (pytest-xdist; fixtures
# that several files share take loopback addresses of their worker's own, tests/loopback.py),
# then those alone: they are CPU-bound or real-time, and failed when a second run shared the
# 2 cores with them. Both run even if the first fails. With ARGS, one serial pytest run.
test: $(VENV)/.installed-test node-deps
ifeq ($(strip $(ARGS)),)
	@status=0; \
	echo "$(PY) -m pytest -n 2 --dist loadfile --ignore=tests/browser -m 'not serial'"; \
	$(PY) -m pytest -n 2 --dist loadfile --ignore=tests/browser -m 'not serial' || status=$$?; \
	echo "$(PY) -m pytest -m 'serial or browser'"; \
	$(PY) -m pytest -m 'serial or browser' || status=$$?; \
	exit $$status
else
	$(PY) -m pytest $(ARGS)
endif

bench: $(VENV)/.installed-test
	$(VENV)/bin/uav-console bench $(ARGS)

lint: $(VENV)/.installed-test
	$(VENV)/bin/ruff check server drone tests bench tools
	$(VENV)/bin/ruff format --check server drone tests bench tools
	$(VENV)/bin/mypy

clean:
	rm -rf $(VENV) tests/node/node_modules .pytest_cache .ruff_cache .mypy_cache
