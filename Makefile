# The two set-up commands of the README:  `make demo` (main job, small default)  and  `make test`.
# Both create .venv and install everything from constraints.txt; torch==2.13.0 (CPU build)
# goes in first. Where it comes from: pip's own configuration (on this project's machines a
# local CPU wheel); elsewhere name a CPU wheel index, e.g.
#   make test TORCH_INDEX=https://download.pytorch.org/whl/cpu
# (a plain PyPI install of torch pulls several GB of CUDA packages).
PYTHON ?= python3
VENV := .venv
TORCH_INDEX ?=
BIN := $(VENV)/bin
OUT ?= out/demo

.PHONY: install browser demo test test-slow clean

$(BIN)/.installed: pyproject.toml constraints.txt
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else "make: Python 3.11 is required (bpy 5.0.1, Blender as a module, exists for 3.11 only); found " + sys.version.split()[0] + ": run make PYTHON=python3.11 ...")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -c constraints.txt $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX)) torch==2.13.0
	$(BIN)/pip install -q -c constraints.txt -e '.[dev]'
	touch $@

install: $(BIN)/.installed

SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)

# Debian's Chromium for the leaderboard's browser test (tests/test_site_browser.py).
browser:
	@command -v chromium >/dev/null || ($(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq chromium >/dev/null)

# The main job on a small default: 12 objects x 10 meshes, every step of the data flow.
demo: install
	$(BIN)/benchmark dataset demo-v3 --data $(OUT)/data
	$(BIN)/basic-shapes info --data $(OUT)/data --figure $(OUT)/info.png
	$(BIN)/basic-shapes show --data $(OUT)/data --object 5 --out $(OUT)/shapes.png
	$(BIN)/radar-sim plot --data $(OUT)/data --object 1 --roll 30 --out $(OUT)/radar.png
	$(BIN)/benchmark reproduce --preset tiny --data $(OUT)/data --out $(OUT)/benchmark --quiet
	$(BIN)/leaderboard seed --from $(OUT)/benchmark/results --data $(OUT)/data --entries $(OUT)/entries
	$(BIN)/leaderboard simulator --data $(OUT)/data --entries $(OUT)/entries
	$(BIN)/leaderboard render --out $(OUT)/site --entries $(OUT)/entries
	@echo "demo outputs in $(OUT)/: info.png, shapes.png, radar.png, benchmark/table.md, site/index.html"
	@echo "preview the leaderboard: $(BIN)/leaderboard serve $(OUT)/site"

test: install browser
	$(BIN)/python -m pytest

# Test by test, not file by file: two of these take 5-7 min each and must not share a process.
test-slow: install
	$(BIN)/python -m pytest -m slow --dist load

clean:
	rm -rf $(VENV) out
