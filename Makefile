# One-command set-up: `make demo` and `make test` both create .venv, install the system library the
# open3d wheel needs (libusb-1.0-0) when it is missing, and install pcdet with its dependencies.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.pcdet-installed

.PHONY: setup demo test sysdeps bench clean

setup: sysdeps $(STAMP)

sysdeps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  echo "installing libusb-1.0-0 (needed by the open3d wheel)"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	fi

# the kernels' sources and headers (setup.py builds every one): a new kernel needs no line here
$(STAMP): pyproject.toml setup.py $(wildcard pcdet/_*.c pcdet/_*.h)
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	@touch $(STAMP)

demo: setup
	$(BIN)/pcdet demo --out demo_out

# one pytest worker per core, at most 4 (pytest-xdist); the tests that start a local Ray instance share one worker
test: setup
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist loadgroup

bench: setup
	$(BIN)/python scripts/bench_peers.py

clean:
	rm -rf $(VENV) demo_out .pytest_cache
