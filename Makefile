# boomtip: `make run` sets everything up and runs the main job on the default scenario;
# `make test` sets everything up and runs the tests. Both are idempotent, and both install the
# versions in requirements.lock (`make lock` resolves them afresh, deliberately).
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
OUT    ?= runs/sts-loaded
SCENARIO ?= sts-loaded
LOCK    = requirements.lock
PIP     = $(BIN)/python -m pip install -q --disable-pip-version-check
# the pcap decoder's test reference (ouster-sdk 1.0's own loader), installed without its pins:
# psutil<6 and rosbags==0.9.23 clash with rerun-sdk's and ours, and reading a pcap needs neither
REFERENCE = ouster-sdk more-itertools

.PHONY: setup run test test-fast bench lock clean

$(BIN)/boomtip: pyproject.toml $(LOCK) Makefile
	bash tools/install_system_deps.sh
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 11), "boomtip needs Python >= 3.11, found " + sys.version'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(PIP) -c $(LOCK) pip
	$(PIP) -c $(LOCK) -e ".[test]"
	$(PIP) -c $(LOCK) --no-deps $(REFERENCE)
	@touch $(BIN)/boomtip

setup: $(BIN)/boomtip

run: setup
	$(BIN)/boomtip run --scenario $(SCENARIO) --out $(OUT) --force --rerun

test: setup
	bash tools/install_system_deps.sh --test
	$(BIN)/python -m pytest

test-fast: setup
	$(BIN)/python -m pytest -m "not slow"

bench: setup
	$(BIN)/boomtip bench raycast --json runs/bench/raycast.json --force
	$(BIN)/boomtip bench perception --json runs/bench/perception.json --force
	$(BIN)/boomtip bench fusion --json runs/bench/fusion.json --force
	$(BIN)/boomtip bench sweep --json runs/bench/sweep.json --force
	$(BIN)/boomtip bench io --json runs/bench/io.json --force
	$(BIN)/boomtip bench ground --json runs/bench/ground.json --force
	$(BIN)/boomtip bench hook --json runs/bench/hook.json --force
	$(BIN)/boomtip bench feeder --json runs/bench/feeder.json --force
	$(BIN)/boomtip bench startup --json runs/bench/startup.json --force
	$(BIN)/boomtip bench process --json runs/bench/process.json --force
	$(BIN)/boomtip bench batch --json runs/bench/batch.json --force
	$(BIN)/boomtip bench lift --json runs/bench/lift.json --force

# Resolve every dependency afresh (the newest releases pyproject.toml allows) into $(LOCK). Run
# `make test` on the result before committing it: the lock holds the versions that passed.
lock:
	rm -rf .venv-lock
	$(PYTHON) -m venv .venv-lock
	.venv-lock/bin/python -m pip install -q --upgrade pip
	.venv-lock/bin/python -m pip install -q ".[test]"
	.venv-lock/bin/python -m pip install -q --no-deps $(REFERENCE)
	.venv-lock/bin/python -m pip freeze --all --exclude-editable | grep -v -i '^boomtip[= ]' > $(LOCK).new
	mv $(LOCK).new $(LOCK)
	rm -rf .venv-lock
	@echo "wrote $(LOCK): now run make test (it reinstalls from the lock)"

clean:
	rm -rf $(VENV) .venv-lock runs *.egg-info
