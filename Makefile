# The two commands a fresh machine needs: `make run` and `make test`.
# Python >= 3.12: on 3.11 asyncio.wait_for swallows a cancel whose result lands in the same loop
# turn (CPython gh-86296). The e-stop does not rest on cancellation, but shutdown is cleaner without
# it. The first interpreter that runs and is new enough wins; pyenv's own versions are looked at too.
PY      ?= $(or $(shell for p in python3.12 python3.13 $$HOME/.pyenv/versions/3.12*/bin/python3.12 \
                  $$HOME/.pyenv/versions/3.13*/bin/python3.13; do \
                  "$$p" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null && \
                  { command -v "$$p"; break; }; done),python3)
PYVER   := $(shell $(PY) -c 'import sys; print("%d.%d" % sys.version_info[:2])')
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed-$(PYVER)
CONFIG  ?= config/farm.toml
ARGS    ?=
CREDENTIALS ?= config/zenoh/credentials.txt

.PHONY: run test bench lint clean mbpoll

$(STAMP): pyproject.toml
	@$(PY) -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null || { echo "fishfarm needs \
	Python 3.12 or newer; found $(PY) $(PYVER) (no python3.12/3.13 on PATH or in ~/.pyenv): give PY=/path/to/python3.12" >&2; exit 2; }
	@if [ -x $(BIN)/python ] && [ "$$($(BIN)/python -c 'import sys; print("%d.%d" % sys.version_info[:2])')" != "$(PYVER)" ]; \
	    then echo "rebuilding $(VENV) for Python $(PYVER)"; rm -rf $(VENV); fi
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

run: $(STAMP) $(CREDENTIALS)
	$(BIN)/fishfarm run --config $(CONFIG) $(ARGS)

# The deployment's Zenoh passwords (config/zenoh/deploy.json5): random, made once, git-ignored.
$(CREDENTIALS): | $(STAMP)
	$(BIN)/fishfarm credentials --out $@

# The layers first (import-linter contracts in pyproject.toml: a broken one fails at once), then
# unit tests sharing the two cores: three workers, as they wait on subprocesses, sockets and ptys a
# fifth of their time (two kept the cores 78 % busy; 2026-12-04, clean clone: 320 s with two, 265 s
# with three). The hardware-in-loop runs then get the machine to themselves, one after another,
# since their farm clocks run hundreds of times faster than the wall (2026-12-05: the farm day beside
# the grow-out on a second worker served feeds 340 farm s late; alone, 4 of 4 within 46 s).
test: $(STAMP) mbpoll
	$(BIN)/lint-imports --no-logo --no-cache
	$(BIN)/python -m pytest -q -n 3 --dist worksteal tests
	$(BIN)/python -m pytest -q hil_tests

# mbpoll (Debian's Modbus master) reads the SCADA register map in tests/controller/scada; its test
# skips, saying why, where apt cannot install it
mbpoll:
	@command -v mbpoll >/dev/null 2>&1 || apt-get install -y -q mbpoll >/dev/null 2>&1 || \
	    { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q mbpoll >/dev/null 2>&1; } || \
	    echo "mbpoll: not installed (apt-get failed); the SCADA mbpoll test will skip"

bench: $(STAMP)
	$(BIN)/python -m bench

lint: $(STAMP)
	$(BIN)/python -m ruff check .

clean:
	rm -rf $(VENV) var build *.egg-info
