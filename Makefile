# Every target that needs the environment depends on `setup`, so each one works as the
# first command on a fresh clone. See README.md.
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
.DEFAULT_GOAL := help
ENV := source ./env.sh >/dev/null &&
BAG ?= bags/sample

.PHONY: help setup demo demo-stream test lint experiments replay bench clean

help:
	@echo 'make setup | demo | demo-stream | test | lint | experiments | replay BAG=<dir> | bench | clean'

setup:
	@bash scripts/setup.sh

demo: setup
	@$(ENV) python scripts/demo.py

demo-stream: setup
	@$(ENV) python scripts/demo_stream.py

test: setup
	@$(ENV) ruff check . && ruff format --check . && python -m pytest tests

lint: setup
	@$(ENV) ruff check . && ruff format --check .

experiments: setup
	@$(ENV) mlkm paper --out results/paper

replay: setup
	@$(ENV) python scripts/replay.py '$(BAG)'

bench: setup
	@$(ENV) mlkm bench --out results/bench

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log
