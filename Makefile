# Every target that needs the environment depends on `setup`, so each one works as the
# first command on a fresh clone; `lint` needs no ROS (scripts/lint.sh). See README.md.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
.DEFAULT_GOAL := help
ENV := source ./env.sh >/dev/null &&
BAG ?= bags/sample

.PHONY: help setup demo demo-stream demo-real demo-network demo-shards test test-fast lint experiments replay bench clean

help:
	@echo 'make <target>:'
	@echo '  setup          .venv, ROS 2 Jazzy, pinned deps, colcon build of ros2_ws (idempotent)'
	@echo '  demo           the live node graph on the default scenario; a bag in bags/'
	@echo '  demo-stream    the open road in stream mode (SUMO sensors); a bag in bags/'
	@echo '  demo-real      real NGSIM traffic replayed from a detector log (log_source); a bag in bags/'
	@echo '  demo-network   the graph on a SUMO road network with junctions (an interchange); a bag'
	@echo '  demo-shards    a long road split over 4 association nodes with track hand-off; a bag'
	@echo '  test           ruff and every test tier (what CI runs: .ci/run)'
	@echo '  test-fast      the tests that need no ROS graph (tests/unit, not marked slow)'
	@echo '  lint           ruff check and format check, without building ROS (scripts/lint.sh)'
	@echo '  experiments    the paper'"'"'s experiments into results/paper/'
	@echo '  replay BAG=<dir>  replay a bag into fresh nodes, print accuracy (default bags/sample)'
	@echo '  bench          benchmarks into results/bench/ (never part of make test)'
	@echo '  clean          remove the colcon build (ros2_ws/build, install, log; build/ros2_tools)'

setup:
	@bash scripts/setup.sh

demo: setup
	@$(ENV) python scripts/demo.py

demo-stream: setup
	@$(ENV) python scripts/demo_stream.py

demo-real: setup
	@$(ENV) python scripts/demo_real.py

demo-network: setup
	@$(ENV) python scripts/demo_network.py

demo-shards: setup
	@$(ENV) python scripts/demo_shards.py

test: setup
	@$(ENV) ruff check . && ruff format --check . && python -m pytest -n 2 --dist loadgroup tests

# tests/unit: ROS-free and in-process tests that start no node and no DDS graph (the tiers
# by path: docs/testing.md); tests marked slow are left to `make test`.
test-fast: setup
	@$(ENV) python -m pytest tests/unit -m 'not slow'

lint:
	@bash scripts/lint.sh

experiments: setup
	@$(ENV) mlkm paper --output results/paper

replay: setup
	@$(ENV) python scripts/replay.py '$(BAG)'

bench: setup
	@$(ENV) mlkm bench --output results/bench

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log build/ros2_tools
