"""Block experiments against the floors of docs/physics.md section 8 (issue: sim_core engine).

10x10x10 block of 0.1 m cubes, E = 1e4 Pa. Each test states the tolerance it proves.
"""

import numpy as np
import pytest

from sim_core import HexMesh, Material, build_model, solve_static, zero_energy_modes
from sim_core.experiments import elongation, flexion, position_errors, shear

BLOCK = dict(shape=(10, 10, 10), spacing=0.1, young_modulus=1e4)
NUS = [0.1, 0.2, 0.3, 0.4, 0.45]


@pytest.mark.parametrize("nu", NUS)
def test_elongation_small_strain_displacement_and_force(nu):
    """1% strain: E within 1% and nu within 0.01, imposed displacement and imposed force."""
    by_displacement = elongation(**BLOCK, poisson_ratio=nu, strain=0.01)
    by_force = elongation(**BLOCK, poisson_ratio=nu, force=0.01 * 1e4 * 1.0)  # sigma = E * 1%
    for result in (by_displacement, by_force):
        assert result.converged and result.residual < 1e-8
        assert result.young_modulus == pytest.approx(1e4, rel=0.01)
        assert result.poisson_ratio == pytest.approx(nu, abs=0.01)
    assert by_force.strain == pytest.approx(0.01, rel=0.01)


@pytest.mark.parametrize("nu", NUS)
def test_elongation_five_percent(nu):
    """5% strain: E within 5% and nu within 0.02."""
    result = elongation(**BLOCK, poisson_ratio=nu, strain=0.05)
    assert result.converged
    assert result.young_modulus == pytest.approx(1e4, rel=0.05)
    assert result.poisson_ratio == pytest.approx(nu, abs=0.02)


def test_fem_reference_measures_its_own_moduli():
    result = elongation(**BLOCK, poisson_ratio=0.3, strain=0.01, model="fem-linear")
    assert result.young_modulus == pytest.approx(1e4, rel=1e-9)
    assert result.poisson_ratio == pytest.approx(0.3, abs=1e-9)


@pytest.mark.parametrize("nu, e_ratio, nu_measured", [(0.1, 0.824, 0.294), (0.3, 1.048, 0.238), (0.45, 1.167, 0.208)])
def test_missing_corrections_are_detected(nu, e_ratio, nu_measured):
    """Physics.md 1: without corrections the block obeys the Cauchy relation (values to 0.005)."""
    result = elongation(**BLOCK, poisson_ratio=nu, strain=0.001, corrections=False, volume_conservation=False)
    assert result.young_modulus / 1e4 == pytest.approx(e_ratio, abs=0.005)
    assert result.poisson_ratio == pytest.approx(nu_measured, abs=0.005)


def test_elongation_has_two_zero_energy_modes():
    """Physics.md 6: under the elongation conditions 2 zero-energy modes remain; E, nu unaffected."""
    result = elongation(**BLOCK, poisson_ratio=0.3, strain=0.01, count_modes=True)
    assert result.zero_energy_modes == 2
    stabilised = elongation(**BLOCK, poisson_ratio=0.3, strain=0.01, count_modes=True, hourglass_control=0.5)
    assert stabilised.zero_energy_modes == 0
    assert stabilised.young_modulus == pytest.approx(result.young_modulus, rel=1e-6)
    assert stabilised.poisson_ratio == pytest.approx(result.poisson_ratio, abs=1e-6)


def test_free_block_has_six_rigid_and_three_zero_energy_modes():
    model = build_model(HexMesh.block((4, 4, 4), 0.1), Material(1e4, 0.3, 1000))
    assert zero_energy_modes(model)[0] == 6 + 3


@pytest.mark.parametrize("angle", [2.0, 10.0])
def test_shear_against_fem(angle):
    """Shear 2 and 10 degrees: %e_dm < 2%, %e_max < 5% against fem-linear, G within 5% of FEM's."""
    mss = shear(**BLOCK, poisson_ratio=0.3, angle_deg=angle)
    fem = shear(**BLOCK, poisson_ratio=0.3, angle_deg=angle, model="fem-linear")
    e_dm, e_max = position_errors(mss, fem)
    assert mss.converged
    assert e_dm < 2.0 and e_max < 5.0
    assert mss.shear_modulus == pytest.approx(fem.shear_modulus, rel=0.05)


@pytest.mark.parametrize("hourglass", [0.0, 0.5])
def test_flexion_against_fem(hourglass):
    """10x5x4 cantilever, tip deflection 2-5% of the length: %e_dm < 5%, %e_max < 10%."""
    kwargs = dict(shape=(10, 5, 4), spacing=0.1, young_modulus=1e4, poisson_ratio=0.3, density=1500.0,
                  gravity=0.04)
    mss = flexion(**kwargs, hourglass_control=hourglass)
    fem = flexion(**kwargs, model="fem-linear")
    assert 0.02 <= -fem.tip_deflection / 1.0 <= 0.05
    e_dm, e_max = position_errors(mss, fem)
    assert e_dm < 5.0 and e_max < 10.0
    assert mss.tip_deflection == pytest.approx(fem.tip_deflection, rel=0.1)


def test_volume_forces_reduce_volume_loss_under_compression():
    """Physics.md 4: 20% compression, nu = 0.45: |dV/V0| drops by > 20% with volume forces
    (kappa = 100 K V0^(2/3)), small-strain E unchanged within 0.2%."""
    mesh = HexMesh.block((6, 6, 6), 1 / 60)
    rest = mesh.element_volumes().sum()

    def volume_change(**options):
        result = elongation((6, 6, 6), 1 / 60, 1e4, 0.45, strain=-0.2, **options)
        assert result.converged
        return mesh.element_volumes(result.positions).sum() / rest - 1

    without = volume_change(volume_conservation=False)
    with_forces = volume_change(volume_stiffness=100.0)
    assert abs(with_forces) < 0.8 * abs(without)
    small = [elongation((6, 6, 6), 1 / 60, 1e4, 0.45, strain=0.01, volume_conservation=v, volume_stiffness=100.0)
             for v in (False, True)]
    assert small[1].young_modulus == pytest.approx(small[0].young_modulus, rel=2e-3)


def test_compressed_block_buckles_without_hourglass_control():
    """Physics.md 6: compression makes the zero-energy modes unstable. A 10 cm block of soft
    tissue (5 kPa, nu = 0.45) under gravity: the pure model's equilibrium is a saddle, with
    hourglass control (alpha = 0.5) it is a minimum."""
    mesh = HexMesh.block((5, 5, 5), 0.02)
    results = {}
    for alpha in (0.0, 0.5):
        model = build_model(mesh, Material(5e3, 0.45, 1060), gravity=(0, -9.81, 0), hourglass_control=alpha)
        control = model.new_control()
        bottom = np.flatnonzero(mesh.nodes[:, 1] == 0)
        control.impose(bottom, mesh.nodes[bottom])
        results[alpha] = solve_static(model, control, check_stability=True)
        assert results[alpha].converged
    assert results[0.0].stable is False
    assert results[0.5].stable is True


@pytest.mark.parametrize(
    "call, word",
    [
        (lambda: elongation((10, 9, 10), 0.1, 1e4, 0.3, strain=0.01), "even ny and nz"),
        (lambda: elongation((10, 10, 10), 0.1, 1e4, 0.3), "exactly one of strain"),
        (lambda: elongation((10, 10, 10), 0.1, 1e4, 0.3, strain=0.01, force=1.0), "exactly one of strain"),
        (lambda: elongation((2, 2, 2), 0.1, 1e4, 0.3, strain=float("nan")), "strain"),
        (lambda: elongation((2, 2, 2), 0.1, 0.0, 0.3, strain=0.01), "young_modulus"),
        (lambda: elongation((2, 2, 2), 0.1, 1e4, 0.5, strain=0.01), "poisson_ratio"),
        (lambda: elongation((2, 2, 2), -0.1, 1e4, 0.3, strain=0.01), "spacing"),
        (lambda: elongation((2, 2, 2), 0.1, 1e4, 0.3, strain=0.01, model="springs"), "model must be one of"),
        (lambda: shear((2, 2, 2), 0.1, 1e4, 0.3, angle_deg=0.0), "angle_deg"),
        (lambda: flexion((2, 2, 2), 0.1, 1e4, 0.3, density=-1.0), "density"),
        (lambda: flexion((2, 2, 2), 0.1, 1e4, 0.3, density=1000, gravity=-1.0), "gravity"),
        (lambda: elongation((2, 2, 2), 0.1, 1e4, 0.3, strain=0.01, model="fem-linear", corrections=False), "unknown options"),
    ],
)
def test_experiment_input_errors(call, word):
    with pytest.raises(ValueError, match=word):
        call()


def test_position_errors_definition():
    rest = np.zeros((3, 3))
    reference = np.array([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 0]])
    result = reference + np.array([[0.1, 0, 0], [0, 0, 0], [0, 0.2, 0]])
    e_dm, e_max = position_errors(result, reference, rest)
    assert e_dm == pytest.approx(np.sqrt((0.01 + 0.04) / 3) / 2 * 100)
    assert e_max == pytest.approx(0.2 / 2 * 100)
    with pytest.raises(ValueError, match="o_max"):
        position_errors(rest, rest, rest)


@pytest.mark.parametrize("nu", [0.49, 0.499])
def test_nearly_incompressible_elongation(nu):
    """nu -> 0.5: stiff corrections, still E within 1% and nu within 0.01 at 1% strain."""
    result = elongation(**BLOCK, poisson_ratio=nu, strain=0.01)
    assert result.converged
    assert result.young_modulus == pytest.approx(1e4, rel=0.01)
    assert result.poisson_ratio == pytest.approx(nu, abs=0.01)
