# One-command entry points. `make demo` and `make test` build .venv first when it is missing or stale.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV ?= .venv
VPY := $(VENV)/bin/python
STAMP := $(VENV)/.setup-done
# Tests run real ROS 2 nodes on loopback only.
TEST_ENV := ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST AMENT_PREFIX_PATH=$(abspath $(VENV))

.PHONY: setup test demo bench clean lint

setup: $(STAMP)

$(STAMP): requirements.txt requirements-ros-wheels.txt requirements-dev.txt constraints-cpu.txt setup.py
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --disable-pip-version-check -q -r requirements.txt -r requirements-ros-wheels.txt \
		-r requirements-dev.txt -c constraints-cpu.txt
	$(VPY) -m pip install --disable-pip-version-check -q --no-deps --no-build-isolation -e .
	# compile fast-hdbscan's numba kernels once into their on-disk cache (the first count would pay 20-80 s)
	$(VPY) -c "from fruitnerfpp_ros.core.clustering.hdbscan_cluster import warm_up; \
		print(f'clustering kernels compiled in {warm_up():.0f} s')"
	touch $@

test: $(STAMP)
	$(TEST_ENV) $(VPY) -m pytest -q test

demo: $(STAMP)
	$(TEST_ENV) $(VENV)/bin/fruitnerfpp demo --out demo_out

lint: $(STAMP)
	$(VPY) -m flake8

bench: $(STAMP)
	$(VPY) bench/cluster_bench.py

clean:
	rm -rf $(VENV) build *.egg-info demo_out .pytest_cache
