# Two commands do all the set-up: `make quickstart` (the main job, small budget) and `make test`.
# Both create or reuse a local virtual environment in .venv and install what they need into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCH := torch==2.13.0
# PyTorch's CPU-only wheels (a plain `pip install torch` on Linux pulls the multi-GB CUDA build): used when
# reachable, else pip's own configured index. Override: `make TORCH_INDEX=URL ...` or the environment;
# `make TORCH_INDEX= ...` uses pip's configured index only.
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu
# More pytest options for `make test`, e.g. PYTEST_ARGS="-m slow" or PYTEST_ARGS="-x tests/test_env.py".
PYTEST_ARGS ?=
# Test processes (pytest-xdist), each given whole test files: a file's module fixtures (trained artifacts)
# are built once. Two keep two cores busy: most tests wait on a subprocess or train one tiny agent.
TEST_WORKERS ?= 2

# torch before the package, so that the package's unpinned `torch` finds it installed.
INSTALL_TORCH = if [ -n "$(TORCH_INDEX)" ] && $(BIN)/python -c "import sys, urllib.request; urllib.request.urlopen(sys.argv[1].rstrip('/') + '/torch/', timeout=15)" "$(TORCH_INDEX)" 2>/dev/null; then \
		echo "Installing $(TORCH), CPU build, from $(TORCH_INDEX)"; \
		$(BIN)/python -m pip install --quiet --index-url "$(TORCH_INDEX)" "$(TORCH)"; \
	else \
		echo "Installing $(TORCH) from pip's configured index ($(if $(TORCH_INDEX),$(TORCH_INDEX) is not reachable,TORCH_INDEX is empty))"; \
		$(BIN)/python -m pip install --quiet "$(TORCH)"; \
	fi

.PHONY: quickstart media test torch lint docs clean-venv

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@$(INSTALL_TORCH)
	$(BIN)/python -m pip install --quiet -e ".[test,bench,distributed,zoo,render,dashboard,fast,mo,cluster,docs]"
	touch $(STAMP)

# Only a virtual environment with torch (what the packaging test installs the built wheel into).
torch:
	$(PYTHON) -m venv $(VENV)
	@$(INSTALL_TORCH)

# The quickstart's run folder: a fixed one, so that the next commands (printed at the end) and the README's
# examples name it; `make quickstart` again replaces it.
QUICKSTART_OUT ?= runs/quickstart

# The fast extra is installed above, so the main job trains with SBX (JAX, ~2.5x faster on these CPUs); the
# models it saves are plain SB3 zips all the same. `hddpg-cli quickstart` alone keeps the SB3 default.
# hddpg-cli lives in $(BIN): the last lines say to activate the virtual environment before using it.
quickstart: $(STAMP)
	$(BIN)/hddpg-cli quickstart --backend sbx --out $(QUICKSTART_OUT) --force
	@echo
	@echo "Next, in this shell (hddpg-cli and the package are in $(VENV)):"
	@echo "  source $(BIN)/activate"
	@echo "  hddpg-cli evaluate $(QUICKSTART_OUT)/hierarchy.zip --episodes 5"
	@echo "  python examples/own_manager.py $(QUICKSTART_OUT)/workers   # your own SAC manager over its workers"

# The README's GIF and the docs' selection figure from the quickstart's run folder, with their record
# (docs/quickstart-media.json, which a test checks against the files and the quickstart's settings).
media: $(STAMP)
	$(BIN)/python -c "import sys; from hddpg_zoo.quickstart_media import publish_media; publish_media(sys.argv[1], 'docs')" $(QUICKSTART_OUT)

# The tests in TEST_WORKERS processes, then the 15 slowest.
test: $(STAMP)
	SDL_VIDEODRIVER=dummy SDL_AUDIODRIVER=dummy $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile --durations=15 $(PYTEST_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check . && $(BIN)/ruff format --check . && $(BIN)/mypy

# The documentation site, docs/_build/html/index.html; a warning (a broken link or reference) fails the build.
docs: $(STAMP)
	$(BIN)/sphinx-build -W --keep-going -q -b html docs docs/_build/html

clean-venv:
	rm -rf $(VENV)
