"""Stability map: explicit and implicit Euler across time step, stiffness, Poisson's ratio and physics.

    python -m benchmarks.stability [--quick]

Scene: a 4 cm cube of soft tissue (4x4x4 elements, rho = 1060 kg/m^3), bottom face fixed, top face
stretched by 1% (imposed), starting at rest. For every E in [1 kPa, 1 MPa], nu in [0.3, 0.499],
physics variant (full model; without corrections; without volume forces; the baudet-hyperelastic
model, without hourglass control) and integrator, it runs
500 steps at dt = ratio * dt_estimate for ratios 0.1 ... 100 and classifies the run:

* stable: not flagged, and the end state is within 10% (of the static displacement) of the static
  equilibrium (``solve_static`` on the same control);
* inaccurate: not flagged and bounded (within 10x the static displacement) but farther than 10%;
* detected divergence: the divergence monitor stopped the run and said why;
* undetected divergence: not flagged but non-finite or beyond 10x the static displacement (must
  never happen).

It also measures the explicit limit by bisection on the time step (a run of 500 steps that stays
bounded) and compares it with ``stable_time_step`` (must agree within 20%). Writes
benchmarks/results/stability.csv, stability_limits.csv and docs/figures/stability_map.png.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from sim_core import HexMesh, Material, build_model, solve_static
from sim_core.files import atomic_path, finish_figure
from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler, run, stable_time_step

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {"full": {}, "no corrections": dict(corrections=False), "no volume forces": dict(volume_conservation=False),
            "baudet-hyperelastic": dict(model="baudet-hyperelastic")}
CATEGORIES = ("stable", "inaccurate", "detected divergence", "undetected divergence")
STEPS = 500


def scene(young_modulus, poisson_ratio, options):
    mesh = HexMesh.block((4, 4, 4), 0.01)
    # the hyperelastic model is stable without hourglass control (and refuses it)
    hourglass = 0.0 if options.get("model") == "baudet-hyperelastic" else 0.5
    model = build_model(mesh, Material(young_modulus, poisson_ratio, 1060.0), hourglass_control=hourglass, **options)
    control = model.new_control()
    y = mesh.nodes[:, 1]
    bottom, top = np.flatnonzero(y == 0), np.flatnonzero(np.isclose(y, y.max()))
    control.impose(bottom, mesh.nodes[bottom])
    control.impose(top, mesh.nodes[top] + [0, 0.0004, 0])
    return model, control


def classify(model, control, integrator, dt, reference, scale):
    state = model.new_state()
    report = run(model, state, integrator, dt, STEPS, control)
    if report.unstable:
        return "detected divergence", report.unstable_reason
    if not np.all(np.isfinite(state.positions)):
        return "undetected divergence", "non-finite"
    error = np.abs(state.positions - reference).max()
    if error > 10 * scale:
        return "undetected divergence", f"error {error:.3g} m"
    return ("stable" if error <= 0.1 * scale else "inaccurate"), f"error/scale {error / scale:.3g}"


def measured_limit(model, control, estimate, reference, scale):
    """Largest dt (bisection, 8 halvings in log space) whose 500-step explicit run stays bounded."""
    low, high = 0.25 * estimate, 4.0 * estimate

    def bounded(dt):
        state = model.new_state()
        report = run(model, state, SymplecticEuler(), dt, STEPS, control)
        return not report.unstable and np.abs(state.positions - reference).max() < 10 * scale

    if not bounded(low):
        return low
    for _ in range(8):
        middle = np.sqrt(low * high)
        low, high = (middle, high) if bounded(middle) else (low, middle)
    return np.sqrt(low * high)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarser grid (for a smoke run)")
    parser.add_argument("--variant", action="append", choices=list(VARIANTS),
                        help="re-run only this variant (repeatable), keeping the others' rows of the CSVs")
    args = parser.parse_args(argv)
    moduli = [1e3, 1e6] if args.quick else [1e3, 1e4, 1e5, 1e6]
    ratios_of = [0.1, 0.9, 2.0, 100.0] if args.quick else [0.1, 0.5, 0.9, 1.1, 2.0, 10.0, 100.0]
    nus = [0.3, 0.499] if args.quick else [0.3, 0.45, 0.49, 0.499]
    rows, limits = [], []
    results = ROOT / "benchmarks" / "results"
    if args.variant:  # keep the other variants' runs (same grid: the committed CSVs)
        rows = [_typed(r) for r in _read_csv(results / "stability.csv") if r["variant"] not in args.variant]
        limits = [_typed(r) for r in _read_csv(results / "stability_limits.csv") if r["variant"] not in args.variant]
    start = time.perf_counter()
    for variant, options in VARIANTS.items():
        if args.variant and variant not in args.variant:
            continue
        for young_modulus in moduli:
            for nu in nus:
                model, control = scene(young_modulus, nu, options)
                reference = solve_static(model, control).positions
                scale = np.abs(reference - model.rest_positions).max()
                estimate = stable_time_step(model, control)
                measured = measured_limit(model, control, estimate, reference, scale)
                limits.append(dict(variant=variant, young_modulus=young_modulus, poisson_ratio=nu,
                                   estimated_dt=estimate, measured_dt=measured, ratio=estimate / measured))
                for name, make in (("explicit", SymplecticEuler), ("implicit", ImplicitEuler)):
                    for ratio in ratios_of:
                        category, detail = classify(model, control, make(), ratio * estimate, reference, scale)
                        rows.append(dict(variant=variant, integrator=name, young_modulus=young_modulus,
                                         poisson_ratio=nu, dt_ratio=ratio, dt=ratio * estimate,
                                         category=category, detail=detail))
                print(f"{variant:>16} E={young_modulus:8.0e} nu={nu:<5} dt_est={estimate:.3e} "
                      f"dt_meas={measured:.3e} est/meas={estimate / measured:.3f}", flush=True)
    order = list(VARIANTS)
    rows.sort(key=lambda r: order.index(r["variant"]))  # stable: each variant's runs in their order
    limits.sort(key=lambda r: order.index(r["variant"]))
    _write_csv(results / "stability.csv", rows)
    _write_csv(results / "stability_limits.csv", limits)
    counts = {c: sum(r["category"] == c for r in rows) for c in CATEGORIES}
    worst = max(abs(l["ratio"] - 1) for l in limits)
    print(f"{len(rows)} runs: " + ", ".join(f"{c}: {n}" for c, n in counts.items()))
    print(f"worst |estimated / measured - 1| = {worst:.1%} over {len(limits)} cases "
          f"({time.perf_counter() - start:.0f} s)")
    _figure(rows, moduli, nus, ratios_of, ROOT / "docs" / "figures" / "stability_map.png")


def _read_csv(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _typed(row):
    """A CSV row with its numeric fields as floats (as the run writes them)."""
    out = {}
    for key, value in row.items():
        try:
            out[key] = float(value) if key not in ("variant", "integrator", "category", "detail") else value
        except ValueError:
            out[key] = value
    return out


def _write_csv(path, rows):
    with atomic_path(path) as temporary, open(temporary, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _figure(rows, moduli, nus, ratios, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    colours = ListedColormap(["#4caf50", "#ffc107", "#2196f3", "#d50000"])
    figure, axes = plt.subplots(2, len(VARIANTS), figsize=(4.2 * len(VARIANTS), 7.5), squeeze=False)
    labels = [f"E={e:.0e}\nnu={nu}" for e in moduli for nu in nus]
    for column, variant in enumerate(VARIANTS):
        for row, integrator in enumerate(("explicit", "implicit")):
            grid = np.full((len(moduli) * len(nus), len(ratios)), np.nan)
            for r in rows:
                if r["variant"] == variant and r["integrator"] == integrator:
                    i = moduli.index(r["young_modulus"]) * len(nus) + nus.index(r["poisson_ratio"])
                    grid[i, ratios.index(r["dt_ratio"])] = CATEGORIES.index(r["category"])
            axis = axes[row, column]
            axis.imshow(grid, cmap=colours, vmin=-0.5, vmax=3.5, aspect="auto")
            axis.set_xticks(range(len(ratios)), [f"{r:g}" for r in ratios])
            axis.set_yticks(range(len(labels)), labels if column == 0 else [""] * len(labels), fontsize=6)
            axis.set_title(f"{integrator}, {variant}", fontsize=9)
            axis.set_xlabel("dt / estimated explicit limit")
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours(i)) for i in range(4)]
    figure.legend(handles, CATEGORIES, loc="lower center", ncol=4)
    figure.suptitle("Stability map: 4 cm tissue cube, 500 steps, top stretched 1% (green: stable and accurate)")
    finish_figure(figure, path, rect=(0, 0.05, 1, 0.97), dpi=100)


if __name__ == "__main__":
    main()
