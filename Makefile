# Every target creates .venv at the repo root on first use.
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# Ray RLlib lives in its own venv: ray[rllib] pins an older gymnasium than .venv's.
RLLIB_VENV := .venv-rllib
RLLIB_STAMP := $(RLLIB_VENV)/.installed

.PHONY: setup demo validate test docs bench bench-peers test-rllib bench-rllib clean

setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# pinned CPU torch first: an unpinned one (pulled by stable-baselines3) is a multi-GB CUDA build
	$(PY) -m pip install --quiet "torch==2.13.0"
	$(PY) -m pip install --quiet -e ".[train,dev,docs]"
	# compile every numba kernel once (260 s of CPU with an empty cache, about 4.5 min; 10 min on 2 busy
	# cores), so that a first env step takes 0.1 s instead of compiling its task's kernels (1.5 min of CPU)
	$(VENV)/bin/tissue-gym-warmup
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m training.demo

validate: $(STAMP)
	$(PY) -m sim_core.studies.demo
	$(PY) -m benchmarks.validation

# two pytest-xdist workers, a test file each at a time (its module fixtures built once): most tests run
# on one core, so two workers halve the wall time of a 2-core machine. TEST_WORKERS=1 runs them in order.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# the documentation site into site/ (mkdocs.yml; docs/gen_pages.py writes the generated pages)
docs: $(STAMP)
	$(PY) docs/gen_pages.py && $(PY) -m mkdocs build --strict --site-dir site

bench: $(STAMP)
	$(PY) -m benchmarks.step_speed
	$(PY) -m benchmarks.env_speed
	$(PY) -m benchmarks.reset_speed
	$(PY) -m benchmarks.snapshots
	$(PY) -m benchmarks.env_speed --integrator static --steps 100 --output benchmarks/results/env_speed_static.json
	$(PY) -m benchmarks.stability
	$(PY) -m benchmarks.env_accuracy
	$(PY) -m benchmarks.dynamic_convergence
	$(PY) -m benchmarks.dynamic_convergence --constant-viscosity --output benchmarks/results/dynamic_convergence_constant_viscosity.json
	$(PY) -m benchmarks.dynamic_convergence --damping-ratio 3 --output benchmarks/results/dynamic_convergence_damping3.json
	$(PY) -m benchmarks.dynamic_convergence --integrator static --output benchmarks/results/dynamic_convergence_static.json
	$(PY) -m benchmarks.env_models
	$(PY) -m benchmarks.env_models --reference-scale 1.5 --output benchmarks/results/env_models_reference_x1.5.json
	$(PY) -m benchmarks.material_range
	$(PY) -m benchmarks.vector_env_speed
	$(PY) -m benchmarks.vector_env_speed --async --rounds 2 --output benchmarks/results/vector_env_speed_async.json
	$(PY) -m benchmarks.vector_env_speed --busy-core --rounds 4 --env tissue_env/TumorPositioning-v0 --output benchmarks/results/vector_env_speed_busy.json
	$(PY) -m benchmarks.training_speed
	$(PY) -m benchmarks.vector_figure
	$(PY) -m benchmarks.palpation_map
	$(PY) -m benchmarks.task_gallery
	$(PY) -m benchmarks.lag_figure
	$(PY) -m benchmarks.speed_accuracy --budget 90
	$(PY) -m benchmarks.memory_soak --randomise
	$(PY) -m benchmarks.cutting
	$(PY) -m benchmarks.cutting --env tissue_env/Dissection-v0 --output benchmarks/results/cutting_dissection.json
	$(PY) -m benchmarks.large_mesh
	$(PY) -m benchmarks.cantilever_reference
	$(PY) -m benchmarks.tet_formulations

# MuJoCo flex and PyBullet soft body next to ours (optional extra, not needed by anything else)
bench-peers: $(STAMP)
	$(PY) -m pip install --quiet -e ".[bench]"
	$(PY) -m benchmarks.peers
	$(PY) -m benchmarks.speed_accuracy_peers
	$(PY) -m benchmarks.speed_accuracy --replot

$(RLLIB_STAMP): pyproject.toml Makefile
	python3 -m venv $(RLLIB_VENV)
	$(RLLIB_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(RLLIB_VENV)/bin/python -m pip install --quiet "torch==2.13.0"
	$(RLLIB_VENV)/bin/python -m pip install --quiet -e ".[rllib,dev]"
	touch $(RLLIB_STAMP)

# RLlib smoke tests on a local Ray instance, and the throughput for 1 and 2 env runners
test-rllib: $(RLLIB_STAMP)
	$(RLLIB_VENV)/bin/python -m pytest -q tests/test_rllib.py

bench-rllib: $(RLLIB_STAMP)
	$(RLLIB_VENV)/bin/python -m benchmarks.rllib_throughput

clean:
	rm -rf $(VENV) $(RLLIB_VENV) build *.egg-info site
