# FurCollide developer commands. Each target bootstraps the pinned .venv first.
PY := .venv/bin/python
.PHONY: venv test test-main test-matrix test-app test-core lint bench demo package mutate docs-images

venv:
	@./scripts/bootstrap.sh

# The README's test command (CI runs exactly this through .ci/run): every lane, i.e. the
# whole suite on bpy 5.0.1, 4.2 LTS, 4.5 LTS and 5.2 LTS, then the real Blender 4.3
# application under Xvfb. Environments are built once, outside the repository
# ($$FURCOLLIDE_CACHE, default /var/cache/furcollide). FURCOLLIDE_LANES=5.0 (or a list)
# runs only some lanes locally.
test: venv
	$(PY) scripts/test_lanes.py all

# Only the main lane (bpy 5.0.1), straight pytest: the quick local loop.
test-main: venv
	$(PY) -m pytest -q tests

# The version matrix: the whole suite on each bpy (4.2, 4.5, 5.0, 5.2).
test-matrix: venv
	$(PY) scripts/test_lanes.py matrix

# The real Blender application (Debian's Blender 4.3 in a trixie chroot, needs root).
test-app: venv
	$(PY) scripts/test_lanes.py app

test-core: venv
	$(PY) -m pytest -q tests/core

# Mutation testing of core/solver.py, rigid.py, soft.py, collider/ and framecache.py
# (docs/testing.md "Mutation testing"): mutmut, pinned in requirements/mutate.txt, one worker under
# nice. Every mutant takes many hours on 2 cores; ARGS="--sample 60" (60 drawn mutants per
# file) about 30 min, ARGS="--files core/framecache.py" 4 min. Results in mutants/.
mutate: venv
	$(PY) -m pip install --disable-pip-version-check -q -r requirements/mutate.txt
	$(PY) scripts/mutate.py $(ARGS)

lint: venv
	$(PY) -m ruff check .

bench: venv
	$(PY) bench/bench_core.py $(ARGS)

.PHONY: bench-pipeline
bench-pipeline: venv
	$(PY) bench/bench_pipeline.py

demo: venv
	$(PY) scripts/demo.py

package: venv
	$(PY) scripts/package.py

# The documentation's screenshots (docs/img/*.png), made by the real Blender application:
# the app lane's chroot (Debian's Blender 4.3 under Xvfb; needs root, built once) walks the
# README's quick start on the demo scene (tests/app/docs_driver.py). About 5 minutes.
docs-images: venv
	$(PY) scripts/docs_images.py
