# Every install step of the project lives here (and in the scripts it calls).
# `make demo` sets up and runs the warehouse patrol demo; `make test` sets up and runs the tests.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PIP    := $(PY) -m pip
FLEET  := $(VENV)/bin/fleet

.PHONY: setup setup-core setup-sumo setup-ros setup-browser demo test test-scale soak bench lint clean

setup: setup-core setup-sumo setup-ros setup-browser

setup-core: $(VENV)/.core-installed
$(VENV)/.core-installed: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -e '.[dev]'
	touch $@

setup-sumo: $(VENV)/.sumo-installed
$(VENV)/.sumo-installed: $(VENV)/.core-installed
	$(PIP) install -q -e '.[dev,sumo]'
	touch $@

setup-ros: setup-core
	VENV=$(VENV) bash tools/setup_ros.sh

# Debian's chromium + chromium-driver (apt-get) for the dashboard's browser tests
setup-browser:
	bash tools/setup_browser.sh

demo: setup-core
	$(FLEET) run configs/warehouse_patrol.yaml --duration 300 --speed 10 --report out/demo_report.json --plot out/demo_trajectories.png

# pytest on two workers (pytest-xdist; tests/conftest.py keeps the ROS tests on one worker and
# a file's tests together), then the `serial` tests alone (they live in tests/fleet/ros, so only
# that directory is collected again); plain `pytest -q` still runs everything in one process
test: setup lint
	$(PY) -m pytest -q -n 2 --dist loadgroup -m 'not scale and not serial'
	$(PY) -m pytest -q -m 'serial and not scale' tests/fleet/ros

# long scale and soak runs (hundreds of robots, simulated hours); CI runs them after `make test`
test-scale: setup
	$(PY) -m pytest -q -m scale

# 8 simulated hours of 200 robots in one process (about 25 min wall on an idle 2-core machine),
# RSS every 10 simulated minutes; SOAK_ARGS=--no-traffic soaks a fleet that keeps driving.
# Outside `make test` and `make test-scale`; figures in docs/performance.md ("Soak").
SOAK_ARGS ?=
soak: setup-core
	$(PY) bench/soak.py --robots 200 --duration 28800 --every 600 $(SOAK_ARGS)

bench: setup
	$(PY) bench/run_all.py

# ruff, strict mypy and the package layout rules (tools/check_layout.py) gate `make test`
lint: setup-core
	$(VENV)/bin/ruff check fleet nodes sim tests bench tools
	$(VENV)/bin/ruff format --check fleet nodes sim tests bench tools
	$(VENV)/bin/mypy
	$(PY) tools/check_layout.py

clean:
	rm -rf $(VENV) out build
