# uav-landing-vision: `make demo` and `make test` are all a newcomer types (see README).
SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
PYTHON ?= python3
VENV := .venv
VENV_STAMP := $(VENV)/.installed
BUILD_STAMP := install/.built
ENV := source scripts/env.sh
APT_PACKAGES := libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri cmake g++ make python3-venv python3-dev libfaketime
BUILD_INPUTS := $(shell find src -type f -not -path '*/__pycache__/*' -not -name '*.pyc') colcon.meta scripts/link_workspace.py

.PHONY: setup apt test demo bench clean

setup: $(BUILD_STAMP)

# Installs the headless GL and build tools when run as root and something is missing.
apt:
	@if ! dpkg -s $(APT_PACKAGES) >/dev/null 2>&1; then \
	  if [ "$$(id -u)" = 0 ]; then \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $(APT_PACKAGES); \
	  else \
	    echo "missing apt packages; run: sudo apt-get install $(APT_PACKAGES)" >&2; exit 1; \
	  fi; \
	fi

$(VENV_STAMP): requirements.txt requirements-dev.txt constraints.txt scripts/fix_ros_wheel_cmake.py
	$(MAKE) apt
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install -q --disable-pip-version-check -r requirements.txt -r requirements-dev.txt -c constraints.txt
	$(VENV)/bin/python scripts/fix_ros_wheel_cmake.py
	touch $@

$(BUILD_STAMP): $(VENV_STAMP) $(BUILD_INPUTS)
	$(ENV) && colcon --log-base build/log build --symlink-install --base-paths src --event-handlers console_cohesion- summary+
	$(VENV)/bin/python scripts/link_workspace.py
	touch $@

test: setup
	$(ENV) && python -m pytest

demo: setup
	$(ENV) && uav-landing demo --out out/demo

bench: setup
	$(ENV) && uav-landing bench

clean:
	rm -rf build install log out .cache
