# The two commands: `make run` (console on the simulator) and `make test` (the whole suite).
# Each creates .venv when missing and keeps it in step with pyproject.toml.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
HOST   ?= 127.0.0.1
PORT   ?= 8000
ARGS   ?=

.PHONY: run test test-lower bench lint node-deps clean

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

# The lower bounds of pyproject.toml, installed as they are written (uv's lowest-direct
# resolution), so that a bound is a version tested: `make test-lower` (in .ci/run after `make
# lint` and `make test`) runs make test's parallel stage on them, whole: every file but the
# browser tests and the tests marked `serial`. Not a subset chosen by imports: the rule "the
# test files that import a bounded library or a module of server/ or drone/ that imports one"
# keeps 138 of the 183 non-browser test files and 83 % of their seconds (the last run's), and
# drops the judges of the test extra's bounds (roslibpy, roslibjs, pyardrone) and 16 files that
# start `uav-console` processes, which import every library; and the bounds found wrong were
# found in files far from the library (OpenCV's NaN pose in a closed-loop flight). The serial
# and browser stages, on wall-clock deadlines, run on the current versions
# in `make test` (on the lower bounds too: `make test-lower ARGS="-m 'serial or browser'"`;
# with ARGS, one pytest run). There tests/test_dependencies.py checks
# (UAV_CONSOLE_LOWER_BOUNDS=1) that each installed version is its bound.
LOWER ?= .venv-lower
$(LOWER)/.installed-test: pyproject.toml
	test -x $(LOWER)/bin/python || $(PYTHON) -m venv $(LOWER)
	$(LOWER)/bin/python -m pip install -q --upgrade pip uv
	VIRTUAL_ENV=$(LOWER) $(LOWER)/bin/uv pip install -q --resolution lowest-direct -e '.[test]'
	touch $(LOWER)/.installed-run $@

tests/node/node_modules/.installed: tests/node/package.json tests/node/package-lock.json
	cd tests/node && npm ci --no-audit --no-fund --loglevel=error
	touch $@

node-deps: tests/node/node_modules/.installed

run: $(VENV)/.installed-run
	$(VENV)/bin/uav-console serve --host $(HOST) --port $(PORT) $(ARGS)

# The whole suite is three pytest runs. First every file but the browser tests and the tests
# marked `serial` in three worker processes on the 2 cores (their files wait on processes and
# real-time flight a third of the time: 216 s against 256-273 s on two, same machine, 2026-11-27),
# one test file per worker at a time (pytest-xdist; fixtures that several files share take
# loopback addresses of their worker's own, tests/support/loopback.py), handed out longest file
# first by the last run's seconds (tests/conftest.py; xdist's own reorder, by test count, is
# off). Then the browser tests the same way in two workers: each has a server and a Chromium of
# its own, and a browser file waits on flights in real time about as much as it computes (in
# three workers they took longer, 221 s, and three failed). Last the `serial` tests alone: they run
# real-time loops and failed when a second run shared the 2 cores with them. All three run even
# if one fails. With ARGS, one serial pytest run.
# Python writes its bytecode during a test run, whatever the environment says: the hundreds of
# processes the tests start then load server/ and drone/ compiled, and every pytest process reads
# the test files' rewritten asserts from the first one's cache (collecting took 9.6 s without).
test test-lower: export PYTHONDONTWRITEBYTECODE :=
PARALLEL := -n 3 --dist loadfile --no-loadscope-reorder --ignore=tests/browser -m 'not serial'
BROWSER := -n 2 --dist loadfile --no-loadscope-reorder tests/browser -m browser
SERIAL := -m 'serial and not browser'
test: $(VENV)/.installed-test node-deps
ifeq ($(strip $(ARGS)),)
	@status=0; \
	for stage in "$(PARALLEL)" "$(BROWSER)" "$(SERIAL)"; do \
		echo "$(PY) -m pytest $$stage"; \
		eval "$(PY) -m pytest $$stage" || status=$$?; \
	done; \
	exit $$status
else
	$(PY) -m pytest $(ARGS)
endif

# On two workers, not make test's three: a run in the slower lowest versions beside three
# others delivered a take-off 2.5 s late (refused by its 2 s deadline), and its time is not
# make test's ten minutes.
test-lower: $(LOWER)/.installed-test node-deps
	UAV_CONSOLE_LOWER_BOUNDS=1 $(LOWER)/bin/python -m pytest $(if $(strip $(ARGS)),$(ARGS),$(subst -n 3,-n 2,$(PARALLEL)))

bench: $(VENV)/.installed-test
	$(VENV)/bin/uav-console bench $(ARGS)

lint: $(VENV)/.installed-test
	$(VENV)/bin/ruff check server drone experiments tests bench tools
	$(VENV)/bin/ruff format --check server drone experiments tests bench tools
	$(VENV)/bin/mypy

clean:
	rm -rf $(VENV) $(LOWER) tests/node/node_modules .pytest_cache .ruff_cache .mypy_cache
