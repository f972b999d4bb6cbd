# Two entry points (README quick start): `make node` runs the live node, `make test` the test suite.
# Each sets up its own virtual environment in .venv (ROS 2 Jazzy rclpy from the package index).
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed
PY := $(VENV)/bin/python

$(STAMP): setup.py setup.cfg package.xml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros,test]'
	touch $(STAMP)

.PHONY: venv node test bench clean
venv: $(STAMP)

node: $(STAMP)
	$(VENV)/bin/driveline_node $(ARGS)

test: $(STAMP)
	$(PY) -m pytest -q test

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
