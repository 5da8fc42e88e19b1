# The README's two commands: `make demo` and `make test`. Both work on a fresh machine, and neither
# modifies a tracked file: the demo writes under runs/demo/ (git-ignored). The committed results in
# results/ change only through `make update-demo-results` (which also regenerates leaderboards/).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# torch pin: the default is the CPU wheel our machines carry. On another machine the package
# index's torch==2.13.0 is the multi-GB CUDA build; for the CPU build there, use e.g.
#   make TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu demo
# or any pin pyproject.toml allows: make TORCH_PIN="torch==2.5.1" demo
TORCH_PIN ?= torch==2.13.0
TORCH_INDEX_URL ?=
DEMO_OUT ?= runs/demo

.PHONY: setup demo test test-fast update-demo-results bench clean

setup: $(STAMP)

# PYTHONWARNINGS: setuptools reports every editable install of a package with renamed folders
# (baselines/ is doabench_baselines) as a warning, "Editable installation. Please be careful with
# folders in your working directory ..."; it is information only (setuptools.warnings.InformationOnly).
$(STAMP): pyproject.toml setup.py Makefile
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet "$(TORCH_PIN)" $(if $(TORCH_INDEX_URL),--index-url "$(TORCH_INDEX_URL)")
	PYTHONWARNINGS="ignore:Editable installation" $(BIN)/pip install --quiet -e ".[test,ray,onnx,torchrir]"  # the Ray, ONNX and torchrir tests run in CI too
	touch $(STAMP)

demo: setup
	$(BIN)/doabench run --tracker srp-max --task sim-demo --out $(DEMO_OUT)

test: setup
	$(BIN)/python -m pytest

# A quick loop while editing: every test but the slow ones (tests/conftest.py, SLOW_TESTS), spread over
# the machine's cores by pytest-xdist (-n auto: one worker a core). `make test` stays the README's and
# CI's command and runs them all, in one process.
test-fast: setup
	$(BIN)/python -m pytest -m "not slow" -n auto

# The explicit command that changes the committed demo results (and the leaderboards built from them).
# Only from a clean tree: the results record the commit they were made with, which must be the code.
update-demo-results: setup
	@test -z "$$(git status --porcelain --untracked-files=no)" || { echo "update-demo-results: the working tree has uncommitted changes (git status); commit them first, so the results record a clean tree" >&2; exit 2; }
	$(BIN)/doabench run --tracker srp-max --task sim-demo --out results --overwrite
	$(BIN)/doabench leaderboard --results results --out leaderboards

clean:
	rm -rf $(VENV) build *.egg-info
