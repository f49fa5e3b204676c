# Two entry points (see README.md): `make demo` runs the main job, `make test` the tests.
# Both create or refresh the virtual environment at .venv and install the project into it.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test lint venv test-venv render-deps mutants readme warm-up
venv: $(VENV)/.installed warm-up
test-venv: $(VENV)/.installed-test warm-up

# The set-up's last step: compile the numba kernels and fused loops of the README's first
# pipeline, and build its FMU, into the caches (~11 s on 2 cores, in parallel), so that the
# first `cosim run` starts at once. It runs every time: a warm cache is recognised in a
# fraction of a second, and an edit recompiles only the kernels it changed. The tests also
# step the safety filter's kernels (~1 min to compile on one core): warmed in parallel here,
# rather than one after the other in whichever test needs them first. The UR5 pipeline
# (tests/test_spatial_blocks.py) adds its FMU and its PD run's fused loop.
WARM_PIPELINES := pipelines/paper_two_link.toml
test-venv: WARM_PIPELINES += pipelines/paper_safety.toml pipelines/ur5.toml
warm-up: $(VENV)/.installed
	$(BIN)/cosim warm-up $(WARM_PIPELINES)

# Software Vulkan (Debian's mesa-vulkan-drivers) so the tests can render the recording in the
# real Rerun viewer without a GPU or display. Without it those tests skip and say why.
LAVAPIPE := /usr/share/vulkan/icd.d/lvp_icd.x86_64.json
render-deps:
	@test -e $(LAVAPIPE) || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    export DEBIAN_FRONTEND=noninteractive; \
	    { apt-get install -y -q mesa-vulkan-drivers || \
	      { apt-get update -q && apt-get install -y -q mesa-vulkan-drivers; }; } >/dev/null \
	      || echo "note: could not install mesa-vulkan-drivers; viewer tests will skip"; \
	  else echo "note: $(LAVAPIPE) is missing (apt-get install mesa-vulkan-drivers as root);" \
	    "viewer tests will skip"; fi; }

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e .
	touch $@

# The test extras (pytest, ruff, Pinocchio, rerun's reader, PythonFMU, MkDocs) on top:
# `make demo` installs only what cosim needs to run.
$(VENV)/.installed-test: $(VENV)/.installed
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

demo: venv
	$(BIN)/cosim run pipelines/paper_two_link.toml --out runs/paper --force

# The documentation site into build/site, strictly: a broken link or an API reference that
# does not resolve fails the build (~2 s). The suite runs on every core (pytest-xdist), a test
# file per worker so that a module's shared runs are made once.
test: test-venv render-deps
	$(BIN)/ruff check .
	$(BIN)/mkdocs build --strict --quiet
	$(BIN)/python -m pytest -n auto --dist loadfile --durations=20

lint: test-venv
	$(BIN)/ruff check .

# The curated mutation run (outside CI's budget: ~1 min per mutant): score and survivors.
mutants: test-venv
	$(BIN)/python benchmarks/mutants.py

# The commands of README.md and docs/ in order with their real runs and sweeps (CI checks
# them with --dry-run): ~20 min on 2 cores, most of it the 500-point Monte Carlo sweep.
readme: test-venv render-deps
	COSIM_README_FULL=1 $(BIN)/python -m pytest -q tests/test_readme.py
