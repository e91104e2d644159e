"""benchmarks/lag_figure.py: a press read by implicit and by static stepping."""

import numpy as np

from benchmarks import lag_figure


def test_implicit_press_settles_on_the_static_reading():
    implicit_depth, implicit = lag_figure.press("implicit")
    static_depth, static = lag_figure.press("static")
    np.testing.assert_array_equal(implicit_depth, static_depth)  # the same probe path
    held = slice(lag_figure.DEPTH_STEPS + lag_figure.HOLD_STEPS - 2, lag_figure.DEPTH_STEPS + lag_figure.HOLD_STEPS)
    # held still, the implicit tissue settles on the static equilibrium (within 0.5%) ...
    np.testing.assert_allclose(implicit[held], static[held], rtol=5e-3)
    # ... while pressing at full speed it reads more than the equilibrium (the tissue lags the probe)
    assert implicit[1] > 1.5 * static[1] > 0
    # the static reading is the same at every held step (to the solve tolerance): no dynamics
    steady = static[lag_figure.DEPTH_STEPS - 1:lag_figure.DEPTH_STEPS + lag_figure.HOLD_STEPS]
    assert np.ptp(steady) <= 1e-4 * steady.max()
