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
	# compile every numba kernel once (about 100 s on 2 cores), so a first env step takes 0.1 s, not 12 s
	$(VENV)/bin/tissue-gym-warmup
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m training.demo

validate: $(STAMP)
	$(PY) -m sim_core.studies.demo
	$(PY) benchmarks/validation.py

test: $(STAMP)
	$(PY) -m pytest -q

# the documentation site into site/ (mkdocs.yml; docs/gen_pages.py writes the generated pages)
docs: $(STAMP)
	$(PY) docs/gen_pages.py && $(PY) -m mkdocs build --strict --site-dir site

bench: $(STAMP)
	$(PY) benchmarks/step_speed.py
	$(PY) benchmarks/env_speed.py
	$(PY) benchmarks/reset_speed.py
	$(PY) benchmarks/env_speed.py --integrator static --steps 100 --output benchmarks/results/env_speed_static.json
	$(PY) benchmarks/stability.py
	$(PY) benchmarks/env_accuracy.py
	$(PY) benchmarks/dynamic_convergence.py
	$(PY) benchmarks/dynamic_convergence.py --constant-viscosity --output benchmarks/results/dynamic_convergence_constant_viscosity.json
	$(PY) benchmarks/dynamic_convergence.py --damping-ratio 3 --output benchmarks/results/dynamic_convergence_damping3.json
	$(PY) benchmarks/dynamic_convergence.py --integrator static --output benchmarks/results/dynamic_convergence_static.json
	$(PY) benchmarks/env_models.py
	$(PY) benchmarks/env_models.py --reference-scale 1.5 --output benchmarks/results/env_models_reference_x1.5.json
	$(PY) benchmarks/material_range.py
	$(PY) benchmarks/vector_env_speed.py
	$(PY) benchmarks/vector_env_speed.py --async --rounds 2 --output benchmarks/results/vector_env_speed_async.json
	$(PY) benchmarks/training_speed.py
	$(PY) benchmarks/vector_figure.py
	$(PY) benchmarks/palpation_map.py
	$(PY) benchmarks/task_gallery.py
	$(PY) benchmarks/lag_figure.py
	$(PY) benchmarks/speed_accuracy.py --budget 90
	$(PY) benchmarks/memory_soak.py --randomise
	$(PY) benchmarks/large_mesh.py

# MuJoCo flex and PyBullet soft body next to ours (optional extra, not needed by anything else)
bench-peers: $(STAMP)
	$(PY) -m pip install --quiet -e ".[bench]"
	$(PY) benchmarks/peers.py
	$(PY) benchmarks/speed_accuracy_peers.py
	$(PY) benchmarks/speed_accuracy.py --replot

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
	$(RLLIB_VENV)/bin/python benchmarks/rllib_throughput.py

clean:
	rm -rf $(VENV) $(RLLIB_VENV) build *.egg-info site
