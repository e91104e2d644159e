"""benchmarks/vector_figure.py draws the committed vector-env and training throughput results."""

from pathlib import Path

import pytest

from benchmarks import vector_figure

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def test_reads_every_mode_of_the_committed_results():
    rates = vector_figure.env_rates(RESULTS)
    assert set(rates) == {"Palpation", "Retraction", "TumorPositioning"}
    for modes in rates.values():
        assert set(modes) == {"sync", "async", "vector 1 thread", "vector"} and min(modes.values()) > 0
    training = vector_figure.training_rates(RESULTS)
    assert {n for _, n in training} == {4, 16} and all(set(r) == {"subproc", "batched"} for r in training.values())


def test_draws_a_figure(tmp_path):
    out = vector_figure.draw(RESULTS, tmp_path / "figure.png")
    assert out.stat().st_size > 10_000


def test_no_results_is_a_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="vector_env_speed"):
        vector_figure.draw(tmp_path, tmp_path / "figure.png")
