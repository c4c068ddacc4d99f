# skyloc: `make demo` runs the pipeline end to end; `make test` installs and runs the tests.
VENV := .venv
PY := $(VENV)/bin/python
export BLENDER_USER_RESOURCES ?= $(CURDIR)/.cache/blender
export XDG_CACHE_HOME ?= $(CURDIR)/.cache/xdg
export NUMBA_CACHE_DIR ?= $(CURDIR)/.cache/numba

.PHONY: install lock lint test test-fast demo bench bench-db bench-match bench-extract bench-blender bench-service clean \
	detector-labels bench-detector bench-terrain campaign campaign-ci \
	image image-smoke multinode-smoke

install:
	bash scripts/install.sh

# pin the installed versions into constraints.txt (after an upgrade that passed `make test`)
lock: install
	{ sed -n '/^#/p' constraints.txt; $(VENV)/bin/pip freeze --exclude-editable | grep -v '^GDAL=='; } > constraints.txt.new
	mv constraints.txt.new constraints.txt

# ruff with the project's rules (pyproject.toml [tool.ruff]); `make test` runs it first
lint: install
	$(VENV)/bin/ruff check .

test: install lint
	$(PY) -m pytest -q

test-fast: install
	$(PY) -m pytest -q -m "not slow and not blender and not service and not grass"

demo: install
	$(PY) -m skyloc.demo

# the report's test campaign (tables 4-8) end to end; DEM=file|procedural:PRESET:SEED, PROFILE=ci|report|full
DEM ?= procedural:mars:7
PROFILE ?= report
SEED ?= 1
CAMPAIGN_OUT ?= campaign_out/$(PROFILE)-seed$(SEED)
campaign: install
	$(VENV)/bin/skyloc campaign --dem "$(DEM)" --profile $(PROFILE) --seed $(SEED) --out "$(CAMPAIGN_OUT)" $(CAMPAIGN_ARGS)

campaign-ci: install
	$(VENV)/bin/skyloc campaign --profile ci --seed $(SEED) --out campaign_out/ci-seed$(SEED)

bench: bench-db bench-match bench-extract bench-blender bench-service

bench-db: install
	$(PY) -m benchmarks.bench_db_render

bench-match: install
	$(PY) -m benchmarks.bench_match

bench-extract: install
	$(PY) -m benchmarks.bench_extract

# issue 11: rendered panoramas + ray-marched truth (cached in /tmp/labels), tuned/validated split by DEM
detector-labels: install
	nice -n 10 $(PY) -m benchmarks.detector_labels --split tune --per-dem 4
	nice -n 10 $(PY) -m benchmarks.detector_labels --split validate --per-dem 3

bench-detector: install
	nice -n 10 $(PY) -m benchmarks.bench_detector --split tune --per-dem 4 --no-speed
	nice -n 10 $(PY) -m benchmarks.bench_detector --split validate --per-dem 3

# multi-resolution terrain horizons vs the full-resolution ones, per cells_per_step (docs/terrain.md)
bench-terrain: install
	nice -n 10 $(PY) -m benchmarks.bench_terrain_levels

bench-blender: install
	$(PY) -m benchmarks.bench_blender
	$(PY) -m benchmarks.bench_sim_acquire --frames 3

bench-service: install
	$(PY) -m benchmarks.bench_service

# issue 14: descent simulator, frame pairs per second at 640 x 480 (see docs/benchmarks.md)
bench-descent-sim: install
	nice -n 10 $(PY) -m benchmarks.bench_descent_sim --frames 30

# issue 15: descent filter, one step per frame pair at N = 64 on one core, peak memory
bench-descent-filter: install
	nice -n 10 $(PY) -m benchmarks.bench_descent_filter --frames 12

# The service image (not part of `make test`: minutes of apt and pip); see docs/service.md.
image:
	bash scripts/image_build.sh

image-smoke:
	bash scripts/image_smoke.sh

multinode-smoke: install
	$(PY) -m pytest -q -m service tests/render_service/test_multinode.py

clean:
	rm -rf .cache build *.egg-info demo_out campaign_out
