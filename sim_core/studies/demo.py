"""``make validate``: run the validation experiments on built-in defaults and print their table.

Reproduces the numbers in the README: 10x10x10 block of 0.1 m cubes (E = 1e4 Pa), elongation for
nu in {0.1, 0.2, 0.3, 0.4, 0.45} by imposed displacement and by imposed force, shear against
linear FEM, the 10x5x4 cantilever against linear FEM, and the stable time step. Writes the table
to docs/validation_table.md and a figure to docs/figures/elongation.png. About a minute on 2 cores.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ..files import atomic_write, finish_figure
from ..solvers.integrators import stable_time_step
from ..models.material import Material
from ..geometry.mesh import HexMesh
from ..models.model import build_model
from .experiments import elongation, flexion, position_errors, shear

ROOT = Path(__file__).resolve().parents[2]
NUS = (0.1, 0.2, 0.3, 0.4, 0.45)
BLOCK = dict(shape=(10, 10, 10), spacing=0.1, young_modulus=1e4)
CANTILEVER = dict(shape=(10, 5, 4), spacing=0.1, young_modulus=1e4, poisson_ratio=0.3, density=1500.0, gravity=0.04)


def elongation_table() -> tuple[list[str], dict]:
    lines = ["| nu | E @1% disp. (Pa) | nu @1% disp. | E @1% force (Pa) | nu @1% force | E @5% (Pa) | nu @5% | E @10% (Pa) | nu @10% |",
             "|---|---|---|---|---|---|---|---|---|"]
    worst = dict(e1=0.0, nu1=0.0, e5=0.0, nu5=0.0)
    for nu in NUS:
        small = elongation(**BLOCK, poisson_ratio=nu, strain=0.01)
        force = elongation(**BLOCK, poisson_ratio=nu, force=100.0)
        medium = elongation(**BLOCK, poisson_ratio=nu, strain=0.05)
        large = elongation(**BLOCK, poisson_ratio=nu, strain=0.10)
        for result in (small, force):
            worst["e1"] = max(worst["e1"], abs(result.young_modulus / 1e4 - 1))
            worst["nu1"] = max(worst["nu1"], abs(result.poisson_ratio - nu))
        worst["e5"] = max(worst["e5"], abs(medium.young_modulus / 1e4 - 1))
        worst["nu5"] = max(worst["nu5"], abs(medium.poisson_ratio - nu))
        lines.append(
            f"| {nu} | {small.young_modulus:.0f} | {small.poisson_ratio:.4f} | {force.young_modulus:.0f} | "
            f"{force.poisson_ratio:.4f} | {medium.young_modulus:.0f} | {medium.poisson_ratio:.4f} | "
            f"{large.young_modulus:.0f} | {large.poisson_ratio:.4f} |")
    return lines, worst


def shear_table() -> list[str]:
    lines = ["| angle | G MSS (Pa) | G FEM (Pa) | %e_dm | %e_max |", "|---|---|---|---|---|"]
    for angle in (2.0, 10.0):
        mss = shear(**BLOCK, poisson_ratio=0.3, angle_deg=angle)
        fem = shear(**BLOCK, poisson_ratio=0.3, angle_deg=angle, model="fem-linear")
        e_dm, e_max = position_errors(mss, fem)
        lines.append(f"| {angle:g} deg | {mss.shear_modulus:.0f} | {fem.shear_modulus:.0f} | {e_dm:.2f} | {e_max:.2f} |")
    return lines


def flexion_table() -> list[str]:
    lines = ["| model | tip deflection (mm) | FEM (mm) | %e_dm | %e_max |", "|---|---|---|---|---|"]
    fem = flexion(**CANTILEVER, model="fem-linear")
    for alpha in (0.0, 0.5):
        mss = flexion(**CANTILEVER, hourglass_control=alpha)
        e_dm, e_max = position_errors(mss, fem)
        label = "baudet" if alpha == 0 else f"baudet, hourglass_control={alpha}"
        lines.append(f"| {label} | {-mss.tip_deflection * 1e3:.1f} | {-fem.tip_deflection * 1e3:.1f} | "
                     f"{e_dm:.2f} | {e_max:.2f} |")
    return lines


def time_step_table() -> list[str]:
    mesh = HexMesh.block((10, 10, 10), 0.1)
    material = Material(1e4, 0.3, 1500.0)
    lines = ["| model | dt limit, undamped (s) | with damping (s) | Gershgorin bound (s) |", "|---|---|---|---|"]
    for label, options in (("springs only", dict(corrections=False, volume_conservation=False)),
                           ("springs + corrections", dict(volume_conservation=False))):
        model = build_model(mesh, material, **options)
        lines.append(f"| {label} | {stable_time_step(model, damping=False):.4f} | {stable_time_step(model):.4f} | "
                     f"{stable_time_step(model, method='gershgorin', damping=False):.4f} |")
    return lines


def elongation_figure(path: Path) -> None:
    strains = [0.01, 0.02, 0.05, 0.1]
    figure = Figure(figsize=(10, 4))
    left, right = figure.subplots(1, 2)
    for nu in NUS:
        full = [elongation(**BLOCK, poisson_ratio=nu, strain=s) for s in strains]
        springs = [elongation(**BLOCK, poisson_ratio=nu, strain=s, corrections=False, volume_conservation=False)
                   for s in strains]
        line, = left.plot(np.array(strains) * 100, [r.young_modulus for r in full], "o-", label=f"nu={nu}")
        left.plot(np.array(strains) * 100, [r.young_modulus for r in springs], "x--", color=line.get_color())
        right.plot(np.array(strains) * 100, [r.poisson_ratio for r in full], "o-", color=line.get_color())
        right.plot(np.array(strains) * 100, [r.poisson_ratio for r in springs], "x--", color=line.get_color())
        right.axhline(nu, color=line.get_color(), lw=0.5)
    left.axhline(1e4, color="k", lw=0.5)
    left.set(xlabel="imposed strain (%)", ylabel="measured E (Pa)", title="Young's modulus (imposed 10 kPa)")
    right.set(xlabel="imposed strain (%)", ylabel="measured nu", title="Poisson's ratio (thin lines: imposed)")
    left.legend(title="o baudet   x springs only", fontsize=8)
    figure.suptitle("Elongation of a 10x10x10 block: corrected Baudet model vs springs without corrections")
    finish_figure(figure, path, dpi=110)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description="Validation table of the Baudet mass-spring model.")
    parser.add_argument("--no-figure", action="store_true")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    elongation_lines, worst = elongation_table()
    sections = [
        "### Elongation, 10x10x10 block of 0.1 m cubes, E = 10 kPa (model `baudet`)", *elongation_lines, "",
        f"Worst at 1% (displacement and force): |E/E0 - 1| = {worst['e1'] * 100:.2f}%, |nu - nu0| = {worst['nu1']:.4f}; "
        f"at 5%: {worst['e5'] * 100:.2f}%, {worst['nu5']:.4f}.", "",
        "### Shear of the same block against linear FEM (nu = 0.3)", *shear_table(), "",
        "### Flexion of the 10x5x4 cantilever (E = 10 kPa, nu = 0.3, rho = 1500, g = 0.04 m/s^2) against linear FEM",
        *flexion_table(), "",
        "### Stable explicit time step, 10x10x10 block (rho = 1500, nu = 0.3, E = 1e4)", *time_step_table(), "",
    ]
    text = "\n".join(sections)
    print(text)
    atomic_write(ROOT / "docs" / "validation_table.md",
                  "<!-- generated by `make validate` (python -m sim_core.studies.demo); do not edit -->\n" + text)
    if not args.no_figure:
        elongation_figure(ROOT / "docs" / "figures" / "elongation.png")
        print(f"figure: {ROOT / 'docs' / 'figures' / 'elongation.png'}")
    print(f"table: {ROOT / 'docs' / 'validation_table.md'}  ({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
