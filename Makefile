# Two commands on a fresh Debian machine with Python 3.11 and gcc:
#   make demo   build the FMUs and run the example end to end
#   make test   run the test suite
#   make docs   build the documentation site into build/docs (executes the worked examples)
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
DEBS   := libtbb12 valgrind

.PHONY: demo test docs bench setup sysdeps clean

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

sysdeps:
	@missing=""; for p in $(DEBS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	fi

setup: sysdeps $(BIN)/.installed

demo: setup
	$(BIN)/motiontwin demo --out build/demo

test: setup
	$(BIN)/python -m pytest -q -n auto --dist loadfile --durations=15

docs: setup
	$(BIN)/python -m sphinx -b html -W --keep-going -q docs build/docs
	@echo "docs: build/docs/index.html"

bench: setup  # one table of every benchmark's ratios; make bench SMOKE=1 for the small sizes
	$(BIN)/python tests/benchmarks/run_all.py $(if $(SMOKE),--smoke)

clean:
	rm -rf build $(VENV)
