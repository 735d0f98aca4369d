# The two set-up commands: `make demo` and `make test`. Both create .venv when it is missing,
# (re)install the project only when pyproject.toml changed, then run.
PYTHON ?= python3
VENV := .venv
VPY := $(VENV)/bin/python
STAMP := $(VENV)/.semslam-installed
DEMO_OUT ?= runs/demo

.PHONY: demo test venv bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --quiet --upgrade pip
	$(VPY) -m pip install --quiet -e ".[test]"
	@# Debian's ROS 1, when installed, reached through a bridge of ROS-only modules (docs/ros1.md; never fatal)
	-$(VPY) -m semslam.run.ros1.bridge --if-present
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/semslam demo --out $(DEMO_OUT) --overwrite

test: $(STAMP)
	$(VPY) -m pytest -q -n 2 --dist loadfile

bench: $(STAMP)
	@echo "benchmarks run on demand: see benchmarks/README.md"

clean:
	rm -rf $(VENV) runs .pytest_cache
