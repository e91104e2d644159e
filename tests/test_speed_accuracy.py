"""benchmarks/speed_accuracy.py: interpolation, Pareto front and a tiny function-level run (< 30 s)."""

import csv

import numpy as np
import pytest

from benchmarks import speed_accuracy as sa
from sim_core import Material
from sim_core.solvers.hyperelastic import NeoHookeanFEM, material_tangent


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_interpolation_is_exact_for_affine_fields(n):
    rng = np.random.default_rng(n)
    gradient, shift = rng.normal(size=(3, 3)) * 0.1, rng.normal(size=3) * 1e-3
    mesh = sa.block(n)
    positions = mesh.nodes + mesh.nodes @ gradient.T + shift
    points = np.vstack([sa.material_points(), rng.uniform(0.0, sa.SIZE, (200, 3)), mesh.nodes])
    u = sa.displacement_at_points(mesh, positions, points)
    assert np.abs(u - (points @ gradient.T + shift)).max() < 1e-12
    index, weights = sa.interpolation_weights(mesh.shape, mesh.spacing, points)
    assert np.allclose(weights.sum(axis=1), 1.0) and weights.min() >= -1e-12


def test_interpolation_reads_nodal_values_at_nodes():
    mesh = sa.block(4)
    values = np.random.default_rng(0).normal(size=(mesh.n_nodes, 3))
    index, weights = sa.interpolation_weights(mesh.shape, mesh.spacing, mesh.nodes)
    assert np.allclose(sa.interpolate(values, index, weights), values, atol=1e-12)


def test_pareto_front_on_a_hand_made_set():
    times = [1.0, 2.0, 3.0, 4.0, 2.0, 0.5, 5.0, 1.0]
    errors = [5.0, 4.0, 4.5, 1.0, 4.0, 9.0, 0.5, 6.0]
    ok = [True, True, True, True, True, True, False, True]
    # 3 is dominated by 1 (2 < 3, 4 < 4.5); 4 duplicates 1 (both kept); 6 is invalid (a diverged run);
    # 7 is dominated by 0 (same time, larger error)
    expected = [True, True, False, True, True, True, False, False]
    assert sa.pareto_front(times, errors, ok).tolist() == expected
    assert sa.pareto_front([1.0, np.nan], [1.0, 0.0]).tolist() == [True, False]


def test_field_errors_definition():
    u_ref = np.array([[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    u = np.array([[0.0, 0.0, 1.0], [0.0, 2.0, 0.0]])
    assert sa.field_errors(u, u_ref) == pytest.approx((25.0, 50.0))
    assert sa.field_errors(u_ref, u_ref) == (0.0, 0.0)


def test_matmul_tangent_matches_the_einsum_definition():
    """NeoHookeanFEM.element_tangents (two batched matmuls) against the direct einsum."""
    mesh = sa.block(2)
    fem = NeoHookeanFEM(mesh, Material(sa.YOUNG, sa.POISSON, sa.DENSITY))
    x = mesh.nodes + np.random.default_rng(1).normal(scale=5e-4, size=mesh.nodes.shape)
    mu, lam = fem.mu[:, None], fem.lam[:, None]  # each element's Lame parameters (Pa) at its quadrature points
    tangent = material_tangent(fem.deformation_gradients(x), mu, lam)
    expected = np.einsum("mp,mpnB,mpaBcD,mpkD->mnakc", fem.weights, fem.gradients, tangent, fem.gradients).reshape(-1, 24, 24)
    actual = fem.element_tangents(x)
    assert abs(actual - expected).max() <= 1e-12 * abs(expected).max()


def test_tool_path_and_ramp():
    assert sa.ramp(0.0) == 0.0 and sa.ramp(sa.RAMP_TIME) == 1.0 and sa.ramp(sa.END_TIME) == 1.0
    # its rate (the peers' imposed tool velocity): the derivative of the ramp, zero before and after it
    for t in np.linspace(0.01, sa.RAMP_TIME - 0.01, 7):
        assert sa.ramp_rate(t) == pytest.approx((sa.ramp(t + 1e-6) - sa.ramp(t - 1e-6)) / 2e-6, rel=1e-6)
    assert sa.ramp_rate(-0.1) == 0.0 and sa.ramp_rate(sa.RAMP_TIME) == 0.0 and sa.ramp_rate(sa.END_TIME) == 0.0
    mesh = sa.block(4)
    path = sa.ScenePath(sa.SCENES["pull"], mesh)
    assert len(path.tool) == 9  # the [1, 3] cm square at 1 cm spacing
    rest = mesh.nodes[path.tool]
    moved = sa.tool_positions(sa.SCENES["pull"], rest, 1.0)
    # a rigid motion: distances within the patch are kept
    d0 = np.linalg.norm(rest[:, None] - rest[None], axis=2)
    d1 = np.linalg.norm(moved[:, None] - moved[None], axis=2)
    assert np.allclose(d0, d1)


def test_tiny_run(tmp_path):
    configs = [sa.Config("baudet", "quasi-static", 2), sa.Config("baudet", "implicit", 2, "bicgstab", 0.05),
               sa.Config("fem-linear", "static-per-step", 2, "LU once"),
               sa.Config("fem-neohookean", "static-per-step", 2, "Newton"), sa.Config(sa.HYPER, "quasi-static", 2),
               sa.Config(sa.HYPER, "implicit", 2, "bicgstab", 0.05)]
    rows, summary = sa.benchmark(resolutions=(2,), reference_resolution=4, configs=configs, scenes=("indentation",),
                                 budget=20.0, verbose=False)
    assert len(rows) == len(configs)
    for row in rows:
        assert row["status"] == "ok", row
        assert np.isfinite(row["error_pct"]) and np.isfinite(row["wall_per_sim_s"]) and row["wall_per_sim_s"] > 0
        assert 0 < row["error_pct"] <= row["error_max_pct"]
    assert any(row["on_pareto"] for row in rows)
    # the floor bookkeeping: cheapest configuration per method within the error, and the verdict
    floor = summary["scenes"]["indentation"]["floor"]
    by_method = summary["scenes"]["indentation"]["cost_to_reach_error"]["by_method"]
    assert set(by_method) == {row["method"] for row in rows} and isinstance(floor["holds"], bool)
    for method, best in by_method.items():
        good = [r for r in rows if r["method"] == method and r["error_pct"] <= sa.FLOOR_ERROR_PCT]
        assert (best is None) == (not good)
    scene = summary["scenes"]["indentation"]
    chain = scene["reference_chain"]
    assert [c["resolution"] for c in chain] == [2, 4]
    assert chain[-1]["error_pct"] == 0.0 and chain[-1]["error_max_pct"] == 0.0  # the reference against itself
    assert scene["reference_convergence"]["error_pct"] == pytest.approx(chain[0]["error_pct"])
    assert scene["reference"]["max_displacement_m"] == pytest.approx(0.002, rel=0.05)  # the probe depth (+ sliding)
    # the neo-Hookean run at n = 2 and the n = 2 reference are the same equilibrium
    neo = next(r for r in rows if r["method"] == "fem-neohookean")
    assert neo["error_pct"] == pytest.approx(chain[0]["error_pct"], rel=1e-5)
    path = tmp_path / "out.csv"
    sa.write_csv(rows, path)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# error_pct")
    read = list(csv.DictReader(lines[1:]))
    assert len(read) == len(rows) and float(read[0]["error_pct"]) == pytest.approx(rows[0]["error_pct"], rel=1e-5)
    back = sa.read_csv(path)  # what --replot draws from
    assert [(r["method"], r["stepping"], r["resolution"], r["on_pareto"]) for r in back] == \
        [(r["method"], r["stepping"], r["resolution"], bool(r["on_pareto"])) for r in rows]
    assert [r["error_pct"] for r in back] == pytest.approx([r["error_pct"] for r in rows], rel=1e-5)
    sa.write_summary(summary, tmp_path / "out.json")
    peers = {"mujoco_version": "test", "rows": [dict(scene="indentation", status="ok", resolution=2, damping="none",
                                                     wall_per_sim_s=0.1, error_pct=5.0)]}
    sa.figure(back, summary, tmp_path / "out.png", peers)
    assert (tmp_path / "out.png").stat().st_size > 1000
    assert not list(tmp_path.glob(".*.tmp")) and not list(tmp_path.glob("*.tmp"))


def test_unstable_runs_are_recorded_not_dropped():
    row, outcome = sa.run_config(sa.Config("baudet", "explicit", 2, "3x limit"), sa.SCENES["indentation"],
                                 sa.material_points(), budget=20.0)
    assert row["status"] == "unstable" and row["reason"] and outcome.positions is None
    assert np.isnan(row["wall_per_sim_s"])
    skipped, _ = sa.run_config(sa.Config("baudet", "quasi-static", 4), sa.SCENES["indentation"], sa.material_points(),
                               budget=1.0, predicted=5.0)
    assert skipped["status"] == "skipped"


def test_capped_solves_do_not_extrapolate_the_warm_start():
    """15-iteration BiCGSTAB solves that stop short on the 16^3 block still read the 2 mm press
    (a warm start extrapolated from capped solves, 2 dv_k - dv_(k-1), amplified their errors: the
    press read 5.6 mm at dt = 50 ms and elements inverted at 20 ms)."""
    points = sa.material_points()
    for dt in (0.05, 0.02):
        row, outcome = sa.run_config(sa.Config("baudet", "implicit", 16, "bicgstab-15", dt), sa.SCENES["indentation"],
                                     points, budget=120)
        assert row["status"] == "ok", row.get("reason")
        assert np.abs(outcome.extra["u_points"]).max() <= 2.05e-3  # the probe presses 2 mm
