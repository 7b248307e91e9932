# The two commands of README.md: `make demo` (main job on the bundled default scene) and `make test`.
VENV := .venv
LFUSD := $(VENV)/bin/lfusd
DEMO_OUT ?= out/default
# The bundled default scene: a 150-frame street with walking people and driving cars, rendered
# as a 3x3 light-field video at a preview size, with every ground-truth key.
DEMO_STAGE ?= stages/street_dynamic_00.usda

.PHONY: setup demo test test-fast lint docs clean
setup:
	@bash scripts/setup.sh

demo: setup
	$(LFUSD) render-video $(DEMO_STAGE) -o $(DEMO_OUT) --rig rig_00 --resolution 128x128 --samples 8
	@echo "dataset written to $(DEMO_OUT); read it with: from lfusd import Dataset; Dataset('$(DEMO_OUT)')"
	@$(VENV)/bin/python -c "from lfusd.truth.coverage import report; print(*report('$(DEMO_OUT)'), sep='\n')"

# One OpenBLAS thread per process: the suite runs two workers and their Blender and CLI processes on
# every core, and NumPy's small linear algebra (4x4 inverses by the thousand) spun a second BLAS
# thread per process against them (a 4x4 inverse took 1 ms instead of 9 us under that load).
test: setup
	OPENBLAS_NUM_THREADS=1 $(VENV)/bin/python -m pytest -q -n auto --dist loadgroup

# The inner loop: everything that needs neither Blender nor a long run (make test stays the full suite).
# Deselecting `blender` arms tests/support/markers.py: a test that starts Blender anyway fails.
test-fast: setup
	OPENBLAS_NUM_THREADS=1 $(VENV)/bin/python -m pytest -q -n auto --dist loadgroup -m "not blender and not slow"

# ruff with the rule set of pyproject.toml; `make test` runs it too (tests/test_lint.py).
lint: setup
	$(VENV)/bin/python -m ruff check .

# The documentation site (mkdocs.yml, docs/) into site/; `make test` builds it too (tests/test_docs.py).
docs: setup
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/python -m mkdocs build --strict

clean:
	rm -rf out site .pytest_cache
