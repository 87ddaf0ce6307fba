# The two commands: `make simulate` and `make test`. Both create .venv on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# Stamps record what was installed, so a second run skips pip unless pyproject changed.
BASE_STAMP := $(VENV)/.installed-base
TEST_STAMP := $(VENV)/.installed-test
BENCH_STAMP := $(VENV)/.installed-bench
# The plot and NetCDF extras (matplotlib, netCDF4: about 215 MB) are for the laptop,
# not the Pi's service: `make simulate` installs them so the first hour needs no pip.
EXTRAS_STAMP := $(VENV)/.installed-extras
# The journal `make export` and `make plot` read: the simulator's, by default.
DB ?= simulate.db

.PHONY: unit-tools browser-tools load-tools test-load test lint typecheck imports pytest coverage simulate extras export plot bench clean install uninstall

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "cc-daemon needs Python >= 3.11; set PYTHON=python3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(BASE_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	@touch $@

$(EXTRAS_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[plot,netcdf,science]'
	@touch $@ $(BASE_STAMP)

$(TEST_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	@touch $@ $(BASE_STAMP) $(EXTRAS_STAMP)

$(BENCH_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	@touch $@ $(TEST_STAMP) $(BASE_STAMP) $(EXTRAS_STAMP)

test: lint typecheck imports pytest

lint: $(TEST_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(TEST_STAMP)
	$(BIN)/mypy

# The floors of docs/architecture.md: every import points down (contracts in pyproject.toml).
imports: $(TEST_STAMP)
	$(BIN)/lint-imports

# The unit's hardening is checked with systemd-analyze (tests/test_unit_hardening.py).
# Where it is missing, install Debian's systemd package if we can (root, apt); else
# those tests skip and say why.
unit-tools:
	@command -v systemd-analyze >/dev/null || { [ "$$(id -u)" -eq 0 ] && command -v apt-get >/dev/null && \
		{ echo "make: installing Debian's systemd package (for systemd-analyze: the unit's checks)" >&2; \
		  apt-get update -qq && apt-get install -y -qq --no-install-recommends systemd >/dev/null; } ; } || \
		echo "make: systemd-analyze not available and cannot be installed: the unit's checks will be skipped" >&2

# The field page's tests drive Debian's headless Chromium through its chromedriver
# (tests/test_web_browser.py). Installed where missing if we can (root, apt); else
# those tests skip and say why.
browser-tools:
	@{ [ -x /usr/bin/chromium ] && [ -x /usr/bin/chromedriver ]; } || { [ "$$(id -u)" -eq 0 ] && command -v apt-get >/dev/null && \
		{ echo "make: installing Debian's chromium and chromium-driver (for the field page's browser tests)" >&2; \
		  apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium chromium-driver >/dev/null; } ; } || \
		echo "make: chromium and chromedriver not available and cannot be installed: the browser tests will be skipped" >&2

# Six workers on two cores: the suite mostly waits on real timers (whole casts end to
# end, 1 s depth reports), not on the CPU. The longest tests are collected first
# (tests/schedule.py) and handed out one at a time, so the workers end together.
pytest: $(TEST_STAMP) unit-tools browser-tools
	$(BIN)/pytest -n 6 --maxschedchunk=1 $(PYTEST_ARGS)

# The whole of `make test` with two CPU hogs beside it (stress-ng --cpu 2, Debian's
# stress-ng, installed like the browser tools): a test that fails only when the machine
# is busy fails here. Run it before landing a change to a test that waits on time
# (docs/development.md). The hogs end with the run, however it ends.
load-tools:
	@command -v stress-ng >/dev/null || { [ "$$(id -u)" -eq 0 ] && command -v apt-get >/dev/null && \
		{ echo "make: installing Debian's stress-ng (the CPU hogs of make test-load)" >&2; \
		  apt-get update -qq && apt-get install -y -qq --no-install-recommends stress-ng >/dev/null; } ; } || \
		{ echo "make: stress-ng not available and cannot be installed: make test-load needs it" >&2; exit 2; }

test-load: load-tools
	@stress-ng --cpu 2 --timeout 3600 --quiet & hogs=$$!; \
		trap 'kill $$hogs 2>/dev/null; wait $$hogs 2>/dev/null' EXIT INT TERM; \
		echo "make: make test beside stress-ng --cpu 2 (pid $$hogs)" >&2; \
		$(MAKE) --no-print-directory test

# The suite with branch coverage (about a fifth slower; make test runs it without).
coverage: $(TEST_STAMP) unit-tools browser-tools
	$(BIN)/pytest -n 6 --maxschedchunk=1 --cov=cc_daemon --cov-branch --cov-report=term:skip-covered $(PYTEST_ARGS)

# make exits 2 for any failure of a recipe: the simulator's own status (docs/simulator.md,
# "Exit status": 3 incomplete, 4 halted, ...) is said on the last line, and is the exit
# status of `.venv/bin/cc-daemon --simulate` run without make.
simulate: $(EXTRAS_STAMP)
	@echo "$(BIN)/cc-daemon --simulate $(ARGS)"
	@$(BIN)/cc-daemon --simulate $(ARGS) || { status=$$?; \
		echo "make: the simulator exited $$status (docs/simulator.md, Exit status); make itself exits 2" >&2; \
		exit $$status; }

extras: $(EXTRAS_STAMP)

# CSV samples, GeoJSON and NetCDF of $(DB), beside it: simulate.csv, .geojson, .nc
export: $(EXTRAS_STAMP)
	$(BIN)/cc-daemon export --db $(DB) --format csv -o $(basename $(DB)).csv
	$(BIN)/cc-daemon export --db $(DB) --format geojson -o $(basename $(DB)).geojson
	$(BIN)/cc-daemon export --db $(DB) --format netcdf -o $(basename $(DB)).nc

# The survey map of $(DB) (simulate-survey.png); with CAST=N, cast N too.
plot: $(EXTRAS_STAMP)
	$(BIN)/cc-daemon plot --db $(DB) --survey -o $(basename $(DB))-survey.png
	$(if $(CAST),$(BIN)/cc-daemon plot --db $(DB) --cast $(CAST) -o $(basename $(DB))-cast-$(CAST).png)

bench: $(BENCH_STAMP)
	$(BIN)/python -m benchmarks

# `sudo make install`: the service, its user, a venv under $(PREFIX), the unit and a
# default config (never overwritten). DESTDIR=dir stages it without touching the machine.
PREFIX ?= /opt/cc-daemon
install:
	DESTDIR="$(DESTDIR)" PREFIX="$(PREFIX)" PYTHON="$(PYTHON)" scripts/install.sh install

uninstall:
	DESTDIR="$(DESTDIR)" PREFIX="$(PREFIX)" scripts/install.sh uninstall

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .coverage
