# Two entry points (README quick start): `make node` runs the live node, `make test` the test suite
# and the docs build. Each sets up its own virtual environment in .venv (ROS 2 Jazzy rclpy from the
# package index). `make docs` builds the documentation site alone (doc/ -> doc/_build/html).
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed
PY := $(VENV)/bin/python

$(STAMP): setup.py setup.cfg package.xml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[ros,test]'
	touch $(STAMP)

.PHONY: venv node test docs bench clean
venv: $(STAMP)

node: $(STAMP)
	@echo 'make node: starting driveline_node, the live driveline (truck_dmf, real time); the first'
	@echo '  start loads and compiles for ~20 s before it logs its topics, rates and how to stop.'
	@echo '  Stop: Ctrl-C (a recording, ARGS="--ros-args -p record:=true", is closed and its bag named).'
	@echo '  The dmf-sim CLI is ready now (after make venv): $(VENV)/bin/dmf-sim, or run'
	@echo '  ". $(VENV)/bin/activate" once; e.g. in another terminal: $(VENV)/bin/dmf-sim monitor'
	$(VENV)/bin/driveline_node $(ARGS)

test: $(STAMP)
	$(PY) -m pytest -q test
	$(MAKE) docs

# -W: any warning (a broken link, a page missing from a toctree, malformed Markdown) fails the
# build; -E: fresh, so a warning is never hidden by an earlier build; no network needed.
docs: $(STAMP)
	$(PY) -m sphinx -W -E -q -b html doc doc/_build/html

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info doc/_build
