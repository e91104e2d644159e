"""Shared set-up of the validation lab (``python -m benchmarks.validation``, issues 3 and 27): the
material (E = 1e4 Pa, rho = 1500 kg/m^3), the model labels and their plot styles, the cantilever and
indentation block several figures load, the CSV and figure writers, and SUMMARY, the dict each
figure adds its headline to (written to benchmarks/results/validation_summary.json by
benchmarks/validation.py)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from sim_core import HexMesh, Material, build_model  # noqa: E402
from sim_core.experiments import elongation, position_errors  # noqa: E402
from sim_core.solvers.static import lowest_eigenvalue, solve_static  # noqa: E402
from sim_core.studies.refinement import clamped_control  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ROOT / "docs" / "figures"
RESULTS = ROOT / "benchmarks" / "results"
E0 = 1e4  # Pa
RHO = 1500.0  # kg/m^3
NUS = (0.1, 0.2, 0.3, 0.4, 0.45)
#: label -> experiment keywords of each mass-spring variant
MSS = {
    "baudet-original": dict(model="baudet-original"),
    "baudet-original + nu factor": dict(model="baudet-original", nu_factor=True),
    "baudet": dict(model="baudet"),
    "baudet-hyperelastic": dict(model="baudet-hyperelastic"),
}
FEM = ("fem-linear", "fem-neohookean")
STYLE = {
    "baudet-original": dict(color="tab:orange", marker="v", linestyle="--"),
    "baudet-original + nu factor": dict(color="tab:red", marker="^", linestyle="--"),
    "baudet": dict(color="tab:blue", marker="o", linestyle="-"),
    "baudet-hyperelastic": dict(color="tab:green", marker="s", linestyle="-"),
    "fem-linear": dict(color="0.35", marker="", linestyle=":"),
    "fem-neohookean": dict(color="black", marker="", linestyle="-"),
}
SUMMARY: dict = {}
#: the cantilever of Fig. 4, 6, 10 and 12: 10x5x4 cubes of 0.1 m, clamped at x = 0
CANTILEVER = dict(shape=(10, 5, 4), spacing=0.1, young_modulus=E0, poisson_ratio=0.3, density=RHO)
#: the indentation block of Fig. 5 and 6: 6x6x6 cubes of 0.1 m, bottom fixed, 3x3-node tool patch
#: (0.2 m square, a third of the width) at the centre of the top face
INDENTER = dict(shape=(6, 6, 6), spacing=0.1, young_modulus=E0, patch=3)


def run_model(experiment, label, **kwargs):
    """Run ``experiment`` with the model named by ``label`` (an MSS variant, an FEM law or a
    ``model_options`` label)."""
    options = model_options(label)
    if experiment is elongation and kwargs.get("strain", 0) < 0 and label != "fem-linear":
        # Ramp compression in 4 increments: moving the loaded face by a whole element in one
        # go can put two nodes on top of each other before Newton starts.
        kwargs.setdefault("load_steps", 4)
    return experiment(**kwargs, **options)


def write_csv(name, rows):
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / f"{name}.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def save(fig, name):
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / f"{name}.png", dpi=110, bbox_inches="tight")
    plt.close(fig)


def rows_of(rows, *models):
    """The rows of each model named, in the order named (a list of rows per model)."""
    return [[r for r in rows if r["model"] == model] for model in models]


def fem_errors(label, runs):
    """Row entries e_dm_vs_<law> and e_max_vs_<law>: %e_dm and %e_max (``position_errors``) of
    ``runs[label]`` against each FEM law's run in ``runs`` (0 against itself)."""
    row = {}
    for reference in FEM:
        e_dm, e_max = position_errors(runs[label], runs[reference]) if label != reference else (0.0, 0.0)
        row[f"e_dm_vs_{reference}"], row[f"e_max_vs_{reference}"] = e_dm, e_max
    return row


def plot_errors(ax, x, e_dm, e_max, label, **cross):
    """A model's %e_dm (its line) and %e_max (crosses of its colour, ``cross`` their options) against x."""
    ax.plot(x, e_dm, markersize=4, **STYLE[label], label=f"{label} %e_dm")
    ax.plot(x, e_max, color=STYLE[label]["color"], marker="x", linestyle="none", label=f"{label} %e_max", **cross)


def finish_grid(fig, axes, ylabels, title, name):
    """A grid of panels (a row per quantity, a column per case) labelled on its first column, the
    legend in its first panel, titled and saved as ``name``."""
    for ax, label in zip(axes[:, 0], ylabels):
        ax.set_ylabel(label)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    save(fig, name)


# == Large deformation: baudet-hyperelastic beside baudet and the FEM laws (issue 27) ==========
HYPER = "baudet-hyperelastic"
#: the models of the large-deformation figures, in drawing order
LARGE = ("baudet", HYPER, "fem-neohookean", "fem-linear")
ALPHA_STYLE = {  # baudet with hourglass control, where a figure shows it
    "baudet, alpha = 0.5": dict(color="tab:purple", marker="D", linestyle="--"),
    "baudet, alpha = 1": dict(color="tab:purple", marker="D", linestyle="--"),
    "baudet, volume_stiffness = 100": dict(color="tab:cyan", marker="d", linestyle="--"),
}


def style(label):
    return STYLE.get(label) or ALPHA_STYLE[label]


def model_options(label):
    """Experiment keywords of a figure label: a model name, or "baudet, alpha = a" / "baudet, volume_stiffness = k"."""
    if label.startswith("baudet, alpha = "):
        return dict(model="baudet", hourglass_control=float(label.split("= ")[1]))
    if label.startswith("baudet, volume_stiffness = "):
        return dict(model="baudet", volume_stiffness=float(label.split("= ")[1]))
    return dict(MSS[label]) if label in MSS else dict(model=label)


def volume_change(result):
    mesh = HexMesh.block(result.parameters["shape"], result.parameters["spacing"])
    return float(mesh.element_volumes(result.positions).sum() / mesh.element_volumes().sum() - 1.0)


def mss_lowest(label, mesh, nu, control, positions, gravity=0.0):
    """Lowest eigenvalue (N/m) of a mass-spring model's constrained tangent at ``positions``."""
    options = model_options(label)
    model = build_model(mesh, Material(E0, nu, RHO), gravity=(0.0, -gravity, 0.0), **options)
    return lowest_eigenvalue(model, control, positions)


def saddle_rings(ax, rows, x, y):
    for r, xi, yi in zip(rows, x, y):
        if r.get("lowest_eigenvalue") is not None and r["lowest_eigenvalue"] < 0:
            ax.plot(xi, yi, "o", mfc="none", color="red", markersize=11)
        if not r["converged"]:
            ax.plot(xi, yi, "kx", markersize=10)


def cantilever(label, gravity, shape=None, spacing=None, nu=None):
    """The clamped cantilever of ``flexion`` solved statically with the stability check for a
    mass-spring label: (positions, converged, lowest eigenvalue N/m)."""
    shape, spacing = shape or CANTILEVER["shape"], spacing or CANTILEVER["spacing"]
    nu = CANTILEVER["poisson_ratio"] if nu is None else nu
    mesh = HexMesh.block(shape, spacing)
    model = build_model(mesh, Material(E0, nu, RHO), gravity=(0.0, -gravity, 0.0), **model_options(label))
    result = solve_static(model, clamped_control(mesh), load_steps=4, check_stability=True)
    return result.positions, result.converged, result.lowest_eigenvalue
