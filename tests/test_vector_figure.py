"""benchmarks/vector_figure.py draws the committed vector-env and training throughput results."""

from pathlib import Path

import pytest

from benchmarks import vector_figure

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def test_reads_every_mode_of_the_committed_results():
    import tissue_env
    rates = vector_figure.env_rates(RESULTS)
    # the default run measures every task with a vector env; the async run (its own command) three of them
    assert set(rates) == {name.split("/")[-1].removesuffix("-v0") for name in tissue_env.VECTOR_ENTRY_POINTS}
    with_async = {"Palpation", "Retraction", "TumorPositioning"}
    for task, modes in rates.items():
        assert set(modes) == {"sync", "vector 1 thread", "vector"} | ({"async"} if task in with_async else set())
        assert min(modes.values()) > 0
    training = vector_figure.training_rates(RESULTS)
    assert {n for _, n in training} == {4, 16} and all(set(r) == {"subproc", "batched"} for r in training.values())


def test_draws_a_figure(tmp_path):
    out = vector_figure.draw(RESULTS, tmp_path / "figure.png")
    assert out.stat().st_size > 10_000


def test_no_results_is_a_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="vector_env_speed"):
        vector_figure.draw(tmp_path, tmp_path / "figure.png")
