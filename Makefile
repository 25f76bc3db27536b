# Developer entry points for a plain virtual environment (no ROS install needed).
# On a robot, build with colcon instead: see test/ros/test_colcon_build.py.

PYTHON ?= python3
VENV := .venv
VENV_PY := $(VENV)/bin/python
# The nodes' environment (make demo), then the toolkit, the flight-log readers, the fleet job
# (Dask) and the test tools on top (make venv, test).
NODES_STAMP := $(VENV)/.stamp-nodes
STAMP := $(VENV)/.stamp
PYTEST_ARGS ?=
# make test runs the suite in three processes (pytest-xdist), one test file each at a time, so
# module fixtures are built once: the ROS tests spend much of their time waiting on node
# start-up and DDS, which the others fill. Three on two cores: beside two busy loops the
# suite took 8 min 8 s, against 10 min 32 s in two. The files go in the order pytest
# collects them (the linters first: test/conftest.py), not by their number of tests.
# TEST_WORKERS=0 runs it in this process.
TEST_WORKERS ?= 3
XDIST := -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder
# The suite starts some 300 interpreters (nodes, commands, Dask workers): each reads the
# package's bytecode from a cache in .venv instead of compiling its sources again, even where
# PYTHONDONTWRITEBYTECODE is set (nothing is written into the checkout either way).
test test-fast: export PYTHONDONTWRITEBYTECODE :=
test test-fast: export PYTHONPYCACHEPREFIX := $(abspath $(VENV))/pycache
# The fast tier's property-based tests draw a quarter of their examples (test/support/fuzz.py).
test-fast: export HYPOTHESIS_PROFILE ?= fast

.PHONY: venv demo test test-fast docs-check bench clean

venv: $(STAMP)

# --use-pep517 makes pip build an editable wheel, so pip itself writes the console
# script into $(VENV)/bin. Without it, pip falls back to the legacy `setup.py develop`
# whenever `wheel` is importable in the venv, and that obeys setup.cfg's
# [develop] script_dir (the ament layout $base/lib/mlx_tempcomp meant for colcon).
$(NODES_STAMP): setup.py setup.cfg package.xml
	test -x $(VENV_PY) || $(PYTHON) -m venv $(VENV)
	$(VENV_PY) -m pip install --quiet --progress-bar off --use-pep517 -e '.[venv]'
	test -x $(VENV)/bin/mlx-tempcomp
	touch $@

$(STAMP): $(NODES_STAMP)
	$(VENV_PY) -m pip install --quiet --progress-bar off --use-pep517 -e '.[venv,toolkit,flightlogs,fleet,test]'
	touch $@

demo: $(NODES_STAMP)
	$(VENV_PY) -m mlx_tempcomp.ros.demo

test: venv
	$(VENV_PY) -m pytest test $(XDIST) $(PYTEST_ARGS)

# The suite without test/ros/ (the nodes over DDS) and the tests marked slow or ros
# elsewhere (setup.cfg): the quick check while working.
test-fast: venv
	$(VENV_PY) -m pytest test --ignore=test/ros $(XDIST) -m 'not ros and not slow' \
		$(PYTEST_ARGS)

# The marked commands of README.md and docs/, run from README's set-up, what they print compared
# with the docs (test/support/docs_check.py; .ci/run runs it after make test).
docs-check: venv
	$(VENV_PY) test/support/docs_check.py --jobs 2

bench: venv
	@set -e; for script in bench/*.py; do \
		[ -e "$$script" ] || continue; \
		echo "== $$script"; \
		$(VENV_PY) "$$script"; \
	done

clean:
	rm -rf $(VENV) build install log .pytest_cache *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
