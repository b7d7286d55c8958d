# aruco_abs_orient — every target sets itself up first (idempotent, seconds when nothing changed).
#   make demo    generate the demo scenario (cached) and run the pipeline on it
#   make test    all tests: the rostests, then the unit tests on two workers (tools/test.sh)
#   make bench   the benchmarks (full-size figures)
#   make lint    ruff, catkin_lint, vermin (Python 3.8 for everything but offline/ and synthetic/), the package's shape
#   make screenshot  rviz headless during a replay -> doc/images/rviz.png (installs rviz, xvfb on demand)
SHELL := /bin/bash
.DEFAULT_GOAL := help
ENV := source tools/env.sh &&
PYTEST_ARGS ?=
# tools/check_structure.py enforces the size limits; STRUCTURE_SIZES=--sizes-warn-only only prints what is over them
STRUCTURE_SIZES ?=

.PHONY: help setup test demo bench lint screenshot clean

help:
	@sed -n '2,7p' Makefile | sed 's/^# //'

setup:
	@bash tools/setup.sh

test: setup
	@$(ENV) bash tools/test.sh $(PYTEST_ARGS)

demo: setup
	@$(ENV) bash tools/demo.sh

bench: setup
	@$(ENV) bash tools/bench.sh

screenshot: setup
	@$(ENV) bash tools/screenshot.sh

lint: setup
	@$(ENV) ruff check . && \
	catkin_lint -W2 --strict $$AAO_WORKSPACE/src/aruco_abs_orient && \
	vermin --target=3.8- --no-tips --violations -q \
	  $$(find src/aruco_abs_orient scripts -name '*.py' -not -path '*/offline/*' -not -path '*/synthetic/*') \
	  $$(grep -l 'python' scripts/* 2>/dev/null) && \
	python tools/check_structure.py $(STRUCTURE_SIZES) && echo "lint: clean"

clean:
	source tools/paths.sh && rm -rf "$$(aao_workspace "$$PWD")" .venv .venv-noetic .pytest_cache .hypothesis .ruff_cache
