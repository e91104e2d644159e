"""Damping you can set: a released cantilever's first-mode damping ratio per time scheme and time step.

    python -m benchmarks.damping        # about a minute on 2 cores

A 1 x 0.2 x 0.2 m beam of 10 x 2 x 2 hexahedra (E = 1 MPa, nu = 0.3, rho = 1000 kg/m^3: first
bending mode near 1.2 Hz; and its 6-tetrahedron split for "baudet"), clamped at x = 0, released
from rest in its first mode shape (tip 1 cm), stepped 3 periods by ``make_solver("implicit", model,
scheme=...)`` (``sim_core.studies.damping``). For each model, scheme and dt in 5, 20, 40 ms: the
damping ratio and natural frequency fitted to the modal amplitude, with the material's damping law
set to zeta = 0.05 at the mode's frequency and set to 0 (what the scheme alone adds), and the wall
time per step. Writes benchmarks/results/damping.json and docs/figures/damping.png (the decay at
5 and 20 ms, implicit Euler and TR-BDF2, against the damped oscillator and its envelope).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sim_core import HexMesh, Material, TetMesh, build_model  # noqa: E402
from sim_core.files import atomic_write, finish_figure  # noqa: E402
from sim_core.studies.damping import decay_fit, first_mode, oscillator, released  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "damping.json"
FIGURE = ROOT / "docs" / "figures" / "damping.png"
E, NU, RHO, ZETA = 1e6, 0.3, 1000.0, 0.05
SCHEMES, STEPS, PERIODS = ("euler", "trapezoidal", "tr-bdf2"), (0.005, 0.02, 0.04), 3.0
CASES = (("hex", "baudet"), ("hex", "baudet-hyperelastic"), ("tet", "baudet"))


def mesh_of(element):
    return (HexMesh if element == "hex" else TetMesh).block((10, 2, 2), 0.1)


def case(element, name):
    """The rows of one model: per scheme, dt and set ratio, the fitted ratio and frequency."""
    mesh = mesh_of(element)
    omega, shape = first_mode(build_model(mesh, Material(E, NU, RHO, damping_ratio=0.0), model=name))
    frequency = omega / (2 * np.pi)
    rows, curves = [], {}
    for zeta in (ZETA, 0.0):
        model = build_model(mesh, Material(E, NU, RHO, damping_ratio=zeta, damping_frequency=frequency), model=name)
        for scheme in SCHEMES:
            for dt in STEPS:
                start = time.perf_counter()
                times, amplitudes = released(model, shape, dt, PERIODS / frequency, scheme)
                seconds = (time.perf_counter() - start) / (len(times) - 1)
                measured, natural = decay_fit(times, amplitudes, omega)
                rows.append(dict(element=element, model=name, scheme=scheme, dt=dt, set_ratio=zeta,
                                 measured_ratio=round(measured, 5), ratio_error=(round(measured / zeta - 1, 4) if zeta
                                                                                  else None),
                                 frequency_ratio=round(natural / omega, 5), eigen_frequency_hz=round(frequency, 5),
                                 seconds_per_step=round(seconds, 6)))
                print(json.dumps(rows[-1]), flush=True)
                if zeta and element == "hex" and name == "baudet":
                    curves[(scheme, dt)] = (times, amplitudes)
    return rows, curves, omega


def figure(curves, omega):
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for axis, dt in zip(axes, (0.005, 0.02)):
        fine = np.linspace(0, curves[("euler", dt)][0][-1], 600)
        axis.plot(fine, oscillator(fine, ZETA, omega), "k-", lw=1, label=f"damped oscillator, zeta = {ZETA}")
        envelope = np.exp(-ZETA * omega * fine)
        axis.plot(fine, envelope, "k:", lw=1, label="its envelope")
        axis.plot(fine, -envelope, "k:", lw=1)
        for scheme, style in (("euler", "s"), ("tr-bdf2", "o")):
            times, amplitudes = curves[(scheme, dt)]
            every = max(1, len(times) // 60)
            axis.plot(times[::every], amplitudes[::every], style, ms=3, mfc="none", label=f"implicit, scheme={scheme!r}")
        axis.set_title(f"dt = {1e3 * dt:g} ms")
        axis.set_xlabel("time after release (s)")
    axes[0].set_ylabel("first-mode amplitude (1 at release)")
    axes[0].legend(fontsize=7, loc="upper right")
    finish_figure(fig, FIGURE, dpi=120)


def main():
    rows, curves, omega = [], {}, None
    for element, name in CASES:
        found, found_curves, found_omega = case(element, name)
        rows += found
        if found_curves:
            curves, omega = found_curves, found_omega
    atomic_write(RESULTS, json.dumps(dict(command="python -m benchmarks.damping", young_modulus=E, poisson_ratio=NU,
                                          density=RHO, shape=[10, 2, 2], spacing=0.1, periods=PERIODS, rows=rows),
                                     indent=1) + "\n")
    figure(curves, omega)


if __name__ == "__main__":
    main()
