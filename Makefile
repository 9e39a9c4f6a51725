# FurCollide developer commands. Each target bootstraps the pinned .venv first.
PY := .venv/bin/python
.PHONY: venv test test-core lint bench demo

venv:
	@./scripts/bootstrap.sh

test: venv
	$(PY) -m pytest -q tests

test-core: venv
	$(PY) -m pytest -q tests -m "not blender"

lint: venv
	$(PY) -m ruff check .

bench: venv
	$(PY) bench/bench_core.py

demo: venv
	$(PY) scripts/demo.py
