# FurCollide developer commands. Each target bootstraps the pinned .venv first.
PY := .venv/bin/python
.PHONY: venv test test-core lint bench demo package

venv:
	@./scripts/bootstrap.sh

# The README's test command (CI runs exactly this through .ci/run).
test: venv
	$(PY) -m pytest -q tests

test-core: venv
	$(PY) -m pytest -q tests/core

lint: venv
	$(PY) -m ruff check .

bench: venv
	$(PY) bench/bench_core.py

.PHONY: bench-pipeline
bench-pipeline: venv
	$(PY) bench/bench_pipeline.py

demo: venv
	$(PY) scripts/demo.py

package: venv
	$(PY) scripts/package.py
