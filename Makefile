# The two commands of README.md: `make demo` (main job on the bundled default scene) and `make test`.
VENV := .venv
LFUSD := $(VENV)/bin/lfusd
DEMO_OUT ?= out/default

.PHONY: setup demo test clean
setup:
	@bash scripts/setup.sh

demo: setup
	$(LFUSD) render stages/default.usda -o $(DEMO_OUT) --samples 16
	@echo "dataset written to $(DEMO_OUT); read it with: from lfusd import Dataset; Dataset('$(DEMO_OUT)')"

test: setup
	$(VENV)/bin/python -m pytest -q

clean:
	rm -rf out .pytest_cache
