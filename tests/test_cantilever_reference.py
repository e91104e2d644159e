"""benchmarks/cantilever_reference.py: the scikit-fem Taylor-Hood cantilever reference does not lock.

On a coarse mesh (10x2x2 cubes, seconds): at nu = 0.3 the mixed u-p solution agrees with the
pure-displacement P2 one; at nu = 0.499 the mixed tip deflection follows its nu = 0.3 value times
Timoshenko's change, while the pure-displacement linear tetrahedron locks.
"""

import math

import pytest

pytest.importorskip("skfem")

from benchmarks import cantilever_reference as ref  # noqa: E402

COARSE = (10, 2, 2)
E = 1e4  # Pa


def tip(poisson, formulation, model="quarter", **kwargs):
    return ref.analyse(COARSE, E, poisson, formulation, model, **kwargs)


def test_mixed_agrees_with_p2_at_moderate_nu():
    mixed, p2 = tip(0.3, "mixed"), tip(0.3, "p2")
    for key in ("tip_mean_uy", "tip_centre_uy"):
        assert mixed[key] < 0
        assert mixed[key] == pytest.approx(p2[key], rel=0.01)


def test_mixed_does_not_lock_and_p1_does():
    mixed_03, mixed_0499 = tip(0.3, "mixed")["tip_mean_uy"], tip(0.499, "mixed")["tip_mean_uy"]
    timoshenko_change = ref.timoshenko_tip_deflection(E, 0.499) / ref.timoshenko_tip_deflection(E, 0.3)
    assert mixed_0499 == pytest.approx(mixed_03 * timoshenko_change, rel=0.10)
    p1_03, p1_0499 = tip(0.3, "p1")["tip_mean_uy"], tip(0.499, "p1")["tip_mean_uy"]
    assert abs(p1_0499) < 0.5 * abs(mixed_0499)  # the linear tetrahedron locks ...
    assert abs(p1_0499) < 0.5 * abs(p1_03)  # ... as nu -> 0.5


def test_quarter_model_is_the_full_mirrored_mesh():
    """The symmetry conditions (u_z = 0 on z = 0; u_x = u_z = p = 0 on y = 0) reproduce the full mesh."""
    quarter = tip(0.499, "mixed", "quarter", density=1000.0, modes=3)
    full = tip(0.499, "mixed", "full", density=1000.0, modes=6)
    for key in ("tip_mean_uy", "tip_centre_uy", "bending_frequency"):
        assert quarter[key] == pytest.approx(full[key], rel=1e-8)
    pair = [m["frequency"] for m in full["modes"] if m["kind"] == "bending"][:2]  # y and z bending
    assert pair[1] == pytest.approx(pair[0], rel=1e-8)
    assert quarter["modes"][0]["kind"] == "bending" and quarter["modes"][0]["direction_deg"] < 1.0
    assert quarter["residual"] < 1e-8 and full["residual"] < 1e-8


def test_timoshenko():
    k = ref.shear_coefficient(0.3)
    assert k == pytest.approx(13 / 15.3)
    bending = ref.LOAD * ref.LENGTH ** 3 / (3 * E * ref.WIDTH ** 4 / 12)
    shear = ref.LOAD * ref.LENGTH / (k * E / 2.6 * ref.WIDTH ** 2)
    assert ref.timoshenko_tip_deflection(E, 0.3) == pytest.approx(bending + shear)
    # shear deformation and rotary inertia lower the frequency a little below Euler-Bernoulli's (L/a = 5)
    ratio = ref.timoshenko_frequency(E, 0.3, 1000.0) / ref.euler_bernoulli_frequency(E, 1000.0)
    assert 0.95 < ratio < 0.995
    # frequency scales as sqrt(E / rho)
    assert ref.timoshenko_frequency(4 * E, 0.3, 1000.0) == pytest.approx(2 * ref.timoshenko_frequency(E, 0.3, 1000.0))


def test_richardson_recovers_a_known_order():
    sizes = [0.1, 0.05, 1 / 30]
    estimate = ref.richardson(sizes, [2.0 + 3.0 * h ** 1.5 for h in sizes])
    assert estimate["observed_order"] == pytest.approx(1.5)
    assert estimate["extrapolated"] == pytest.approx(2.0)
    assert math.isfinite(estimate["gci_fine"]) and estimate["monotone"]
