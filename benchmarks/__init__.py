"""The benchmark and figure scripts of tissue-gym: speed, accuracy, stability, memory and training
measurements of sim_core and tissue_env, each writing its results to ``benchmarks/results/`` (and
its figures to ``docs/figures/``), plus the validation lab. This package is not installed with the
library (only ``sim_core`` and ``tissue_env`` are): run each script as a module from the repository
root, ``python -m benchmarks.<name>`` (for example ``python -m benchmarks.env_speed --help``), so
that ``training`` and the sibling benchmark modules import from the clone; ``make bench`` runs them.
"""
