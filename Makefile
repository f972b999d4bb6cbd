# Two entry points (README quick start): `make node` runs the live node, `make test` the test suite
# and the docs build. Installing runs `dmf-sim warm-up` once: the numerical kernels compile into
# numba's cache (~1 min) where one expects to wait, not in the first command or node start. Each sets up its own virtual environment in .venv (ROS 2 Jazzy rclpy from the
# package index). `make docs` builds the documentation site alone (doc/ -> doc/_build/html).
# CI (`make ci`, .ci/run) runs the suite in two more environments: the ROS platform's library
# versions (constraints/platform-jazzy.txt, .venv-jazzy) and an install without the ros extra
# (.venv-noros: the ROS tests are skipped with their reason, everything else must pass). Every
# environment has the feature extras ([all]: design, optimize, durability, foxglove); the
# one-line error a missing extra gives is tested by simulating the missing library.
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed
PY := $(VENV)/bin/python
DEPS := setup.py setup.cfg package.xml
PYTEST := -m pytest -q -rs --durations=15 test

PLATFORM := constraints/platform-jazzy.txt
VENV_JAZZY := .venv-jazzy
VENV_NOROS := .venv-noros

$(STAMP): $(DEPS)
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[all,ros,test]'
	$(VENV)/bin/dmf-sim warm-up
	touch $(STAMP)

$(VENV_JAZZY)/.installed: $(DEPS) $(PLATFORM)
	$(PYTHON) -m venv $(VENV_JAZZY)
	$(VENV_JAZZY)/bin/python -m pip install --quiet --upgrade pip
	$(VENV_JAZZY)/bin/python -m pip install --quiet -c $(PLATFORM) -e '.[all,ros,test]'
	$(VENV_JAZZY)/bin/dmf-sim warm-up
	touch $@

$(VENV_NOROS)/.installed: $(DEPS)
	$(PYTHON) -m venv $(VENV_NOROS)
	$(VENV_NOROS)/bin/python -m pip install --quiet --upgrade pip
	$(VENV_NOROS)/bin/python -m pip install --quiet -e '.[all,test]'
	$(VENV_NOROS)/bin/dmf-sim warm-up
	touch $@

.PHONY: venv node test test-platform test-noros ci docs bench clean
venv: $(STAMP)

node: $(STAMP)
	@echo 'make node: starting driveline_node, the live driveline (truck_dmf, real time); it loads'
	@echo '  for a few seconds (make venv compiled its kernels: dmf-sim warm-up) before it logs its'
	@echo '  topics, rates and how to stop.'
	@echo '  Stop: Ctrl-C (a recording, ARGS="--ros-args -p record:=true", is closed and its bag named).'
	@echo '  The dmf-sim CLI is ready now (after make venv): $(VENV)/bin/dmf-sim, or run'
	@echo '  ". $(VENV)/bin/activate" once; e.g. in another terminal: $(VENV)/bin/dmf-sim monitor'
	$(VENV)/bin/driveline_node $(ARGS)

# everything, ROS included: a missing rclpy is an error here, not a skip
test: $(STAMP)
	DMF_SIM_REQUIRE_ROS=1 $(PY) $(PYTEST)
	$(MAKE) docs

# the suite on the ROS 2 Jazzy platform's versions (numpy 1.26, matplotlib 3.6, ...)
test-platform: $(VENV_JAZZY)/.installed
	$(VENV_JAZZY)/bin/python -c "import numpy, matplotlib; print('platform: numpy', \
	    numpy.__version__, 'matplotlib', matplotlib.__version__)"
	DMF_SIM_PLATFORM=jazzy DMF_SIM_REQUIRE_ROS=1 $(VENV_JAZZY)/bin/python $(PYTEST)

# `pip install -e '.[all,test]'`, no ROS: the suite collects, ROS tests skipped (-rs shows why)
test-noros: $(VENV_NOROS)/.installed
	$(VENV_NOROS)/bin/python -c "import importlib.util, sys; \
	    sys.exit('rclpy is installed in $(VENV_NOROS)') if importlib.util.find_spec('rclpy') \
	    else None"
	$(VENV_NOROS)/bin/python $(PYTEST)

ci: test test-platform test-noros

# -W: any warning (a broken link, a page missing from a toctree, malformed Markdown) fails the
# build; -E: fresh, so a warning is never hidden by an earlier build; no network needed.
docs: $(STAMP)
	$(PY) -m sphinx -W -E -q -b html doc doc/_build/html

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) $(VENV_JAZZY) $(VENV_NOROS) build *.egg-info doc/_build
