# boomtip: `make run` sets everything up and runs the main job on the default scenario;
# `make test` sets everything up and runs the tests. Both are idempotent.
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
OUT    ?= runs/sts-loaded
SCENARIO ?= sts-loaded

.PHONY: setup run test bench clean

OUSTER_SDK ?= ouster-sdk==1.0.1

$(BIN)/boomtip: pyproject.toml Makefile
	bash tools/install_system_deps.sh
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "boomtip needs Python >= 3.11, found " + sys.version' 
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test,ouster]"
	# without its pins, which conflict with rerun-sdk's (see pyproject.toml)
	$(BIN)/python -m pip install -q --no-deps "$(OUSTER_SDK)"
	@touch $(BIN)/boomtip

setup: $(BIN)/boomtip

run: setup
	$(BIN)/boomtip run --scenario $(SCENARIO) --out $(OUT) --force --rerun

test: setup
	$(BIN)/python -m pytest

bench: setup
	$(BIN)/boomtip bench raycast --json runs/bench/raycast.json --force
	$(BIN)/boomtip bench perception --json runs/bench/perception.json --force
	$(BIN)/boomtip bench fusion --json runs/bench/fusion.json --force
	$(BIN)/boomtip bench sweep --json runs/bench/sweep.json --force
	$(BIN)/boomtip bench io --json runs/bench/io.json --force
	$(BIN)/boomtip bench ground --json runs/bench/ground.json --force
	$(BIN)/boomtip bench hook --json runs/bench/hook.json --force
	$(BIN)/boomtip bench feeder --json runs/bench/feeder.json --force

clean:
	rm -rf $(VENV) runs *.egg-info
