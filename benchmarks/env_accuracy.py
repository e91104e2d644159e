"""Are the environments' observations accurate at their default resolution? (issue 4, issue 6 sec. 3)

For each task this reproduces the environment's scene at its defaults (geometry, material, attached
face, tool, gravity, floor, inclusion) with ``sim_core.resolution.Scene``, solves a representative
set of tool displacements inside the env's workspace with the ``fem-neohookean`` reference on a
fine mesh and with the mass-spring model (static equilibrium, stability checked) at resolutions
2..8 (elements no longer than max(size) / n) for hourglass_control in {0, 0.25, 0.5, 1} and
volume_stiffness in {1, 100}, and reports
- the env's current default (shape, hourglass_control = 0.5, volume_stiffness = 1): its errors on
  the tool force, the target position and the volume change, and whether its equilibria are stable;
- what ``choose_resolution`` recommends for a tolerance of 5% (and the closest candidate when
  nothing meets it).

Scenes (SI units; tool displacements from rest, y up):
- TumorPositioning: 5 cm cube, bottom fixed, tool = the 3x3 central top nodes at 4x4x4 (a 2.5 cm
  square, glued), target = the block centre; displacements: press 6 and 12 mm, pull 12 mm, drag
  12 mm along x, (8, -8, 8) mm (goals are 6-12 mm tool moves, the workspace +-20 mm).
- Palpation: 6 x 3 x 6 cm slab, bottom fixed, inclusion (the default cell 1.2 x 1 x 1.2 cm,
  1-2 cm deep, 10x stiffer), a frictionless flat probe of radius 9 mm (0.75 element at 5x3x5, only
  u_y imposed on the top nodes under it) pressed 2, 4, 6, 8 mm (the env's max_depth) at three
  places: over the inclusion, between nodes away from it, and on a node of the default mesh;
  target = the inclusion centre.
- Retraction: 6 x 0.8 x 3 cm flap on a frictionless floor, edge x = 0 attached, tool = the face
  x = 6 cm (glued), target = the flap's centre; the scripted lift-and-pull path, by continuation:
  lift 10, 20, 40 mm, then back 20 mm and 40 mm at 45 mm height.

Writes benchmarks/results/env_accuracy.json and docs/figures/env_accuracy.png; prints a table.
Run: python -m benchmarks.env_accuracy [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim_core.resolution import Scene, choose_resolution, evaluate, reference_solutions  # noqa: E402

MM = 1e-3
E, NU, RHO, G = 5.0e3, 0.45, 1060.0, 9.81
TOLERANCE = 0.05


def tumor_scenes():
    # tissue_env.TumorPositioningEnv defaults: size 5 cm, shape (4, 4, 4), tool = top nodes within
    # 1.5 elements of the centre = the 3x3 nodes spanning [1.25, 3.75] cm in x and z.
    return [Scene(size=0.05, young_modulus=E, poisson_ratio=NU, density=RHO, gravity=G, fixed_face="y-",
                  tool_low=(0.0125, 0.05, 0.0125), tool_high=(0.0375, 0.05, 0.0375),
                  displacements=[(0, -6 * MM, 0), (0, -12 * MM, 0), (0, 12 * MM, 0), (12 * MM, 0, 0),
                                 (8 * MM, -8 * MM, 8 * MM)],
                  target=(0.025, 0.025, 0.025), name="TumorPositioning")]


def palpation_scenes():
    # tissue_env.PalpationEnv defaults: size (6, 3, 6) cm, shape (5, 3, 5), probe radius 0.75 *
    # 1.2 cm, inclusion = the middle candidate cell (2, 1, 2), 10x E; only u_y of the touched
    # top nodes is imposed; max_depth 8 mm.
    size = np.array([0.06, 0.03, 0.06])
    path = [[(0, -d * MM, 0) for d in (2, 4, 6, 8)]]
    scenes = []
    for label, (x, z) in (("over inclusion", (0.030, 0.030)), ("between nodes", (0.018, 0.042)),
                          ("on a node", (0.012, 0.048))):
        scenes.append(Scene(
            size=size, young_modulus=E, poisson_ratio=NU, density=RHO, gravity=G, fixed_face="y-",
            tool_low=(x, 0.03, z), tool_high=(x, 0.03, z), tool_radius=0.009, tool_components=(1,),
            displacements=path, target=(0.030, 0.015, 0.030), inclusion_low=(0.024, 0.01, 0.024),
            inclusion_high=(0.036, 0.02, 0.036), inclusion_ratio=10.0, name=f"Palpation ({label})"))
    return scenes


def retraction_scenes():
    # tissue_env.RetractionEnv defaults: size (6, 0.8, 3) cm, shape (6, 1, 3), face x = 0 attached,
    # tool = face x = 6 cm (glued), floor y >= 0, gravity; workspace x -6..+1 cm, y 0..6 cm.
    path = [[(0, 10 * MM, 0), (0, 20 * MM, 0), (0, 40 * MM, 0), (-20 * MM, 45 * MM, 0), (-40 * MM, 45 * MM, 0)]]
    return [Scene(size=(0.06, 0.008, 0.03), young_modulus=E, poisson_ratio=NU, density=RHO, gravity=G,
                  fixed_face="x-", tool_low=(0.06, 0.0, 0.0), tool_high=(0.06, 0.008, 0.03), floor=True,
                  displacements=path, target=(0.03, 0.004, 0.015), name="Retraction")]


TASKS = {
    # name: (scenes, env default shape, env default hourglass_control, reference resolution)
    "TumorPositioning": (tumor_scenes, (4, 4, 4), 0.5, 8),
    "Palpation": (palpation_scenes, (5, 3, 5), 0.5, 10),
    "Retraction": (retraction_scenes, (6, 1, 3), 0.5, 15),
}


def _fmt(errors):
    return "-" if errors is None else " ".join(f"{errors[q] * 100:6.1f}" for q in ("force", "target", "volume"))


def run(quick=False):
    resolutions = range(2, 7) if quick else range(2, 9)
    hourglass, volume = ((0.0, 0.5), (1.0, 100.0)) if quick else ((0.0, 0.25, 0.5, 1.0), (1.0, 100.0))
    out = dict(tolerance=TOLERANCE, resolutions=list(resolutions), hourglass_controls=list(hourglass),
               volume_stiffnesses=list(volume), error_definition=(
                   "max over tested displacements of |q - q_ref| / max |q_ref|; q = tool force (3,), target "
                   "displacement (3,), relative volume change; reference fem-neohookean"), tasks={})
    start = time.perf_counter()
    for name, (make, default_shape, default_alpha, reference_resolution) in TASKS.items():
        scenes = make()
        clock = time.perf_counter()
        references = reference_solutions(scenes, reference_resolution=reference_resolution)
        default = evaluate(scenes, default_shape, references[0], TOLERANCE, hourglass_control=default_alpha,
                           volume_stiffness=1.0)
        choice = choose_resolution(scenes, TOLERANCE, resolutions=resolutions, hourglass_controls=hourglass,
                                   volume_stiffnesses=volume, references=references, full_scan=True)
        reference_values = [dict(scene=s.name, force=r.force.tolist(), target_displacement=(r.target - r.target_rest).tolist(),
                                 volume=r.volume.tolist(), stable=[bool(v) for v in r.stable])
                            for s, r in zip(scenes, references[0])]
        # the same candidates judged on the tool force and the target only, at 5% and 10% (the
        # volume change is a second-order quantity where the mass-spring law departs most)
        relaxed = {f"force_target_{int(t * 100)}pct": _pick(choice.candidates, {"force": t, "target": t})
                   for t in (TOLERANCE, 0.10)}
        out["tasks"][name] = dict(relaxed=relaxed,
            scenes=[s.name for s in scenes], displacements_m=[[p.tolist() for p in s.displacements] for s in scenes],
            env_default=dict(shape=list(default_shape), hourglass_control=default_alpha, volume_stiffness=1.0,
                             **{k: v for k, v in default.summary().items() if k not in ("shape", "hourglass_control", "volume_stiffness")}),
            reference_values=reference_values, wall_time=time.perf_counter() - clock, **choice.summary())
        print(f"{name}: {time.perf_counter() - clock:.0f} s", flush=True)
    out["total_time"] = time.perf_counter() - start
    results = ROOT / "benchmarks" / "results"
    results.mkdir(parents=True, exist_ok=True)
    (results / "env_accuracy.json").write_text(json.dumps(out, indent=1, default=float))
    figure(out)
    table(out)
    return out


def _pick(candidates, tolerance):
    """The coarsest converged, stable candidate within ``tolerance`` ({quantity: value}), the one
    with the smallest worst error / tolerance at that resolution (choose_resolution's rule)."""
    good = [c for c in candidates if c.converged and c.stable and c.errors is not None
            and all(c.errors[q] <= t for q, t in tolerance.items())]
    if not good:
        return None
    coarsest = min(c.n_nodes for c in good)
    best = min((c for c in good if c.n_nodes == coarsest), key=lambda c: max(c.errors[q] / t for q, t in tolerance.items()))
    return best.summary()


def table(out):
    print(f"\nerrors in % (force / target / volume) against fem-neohookean, tolerance {out['tolerance'] * 100:g}%")
    print(f"{'task':17s} {'setting':40s} {'force target volume':>20s}  stable  admissible")
    for name, task in out["tasks"].items():
        d = task["env_default"]
        print(f"{name:17s} {'default ' + str(tuple(d['shape'])) + ' hg=' + str(d['hourglass_control']) + ' vs=1':40s} "
              f"{_fmt(d['errors']):>20s}  {str(d['stable']):6s}  {d['admissible']}")
        for label in ("chosen", "best"):
            c = task[label]
            if c is None:
                print(f"{'':17s} {label + ': none':40s}")
                continue
            setting = f"{label} n={c['resolution']} {tuple(c['shape'])} hg={c['hourglass_control']:g} vs={c['volume_stiffness']:g}"
            print(f"{'':17s} {setting:40s} {_fmt(c['errors']):>20s}  {str(c['stable']):6s}  {c['admissible']}")
        for key, c in task["relaxed"].items():
            label = key.replace("force_target_", "F+x <= ").replace("pct", "%")
            setting = "none" if c is None else (f"n={c['resolution']} {tuple(c['shape'])} hg={c['hourglass_control']:g} "
                                                f"vs={c['volume_stiffness']:g}")
            print(f"{'':17s} {label + ': ' + setting:40s} {'' if c is None else _fmt(c['errors']):>20s}")
    print(f"total {out['total_time']:.0f} s")


def figure(out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = out["tasks"]
    fig, axes = plt.subplots(1, len(tasks), figsize=(5.2 * len(tasks), 4.3), squeeze=False)
    for ax, (name, task) in zip(axes[0], tasks.items()):
        tol = out["tolerance"]
        settings = sorted({(c["hourglass_control"], c["volume_stiffness"]) for c in task["candidates"]})
        for i, (alpha, kappa) in enumerate(settings):
            rows = [c for c in task["candidates"] if c["hourglass_control"] == alpha and c["volume_stiffness"] == kappa
                    and c["errors"] is not None]
            if not rows:
                continue
            n = [c["resolution"] for c in rows]
            worst = [max(c["errors"].values()) * 100 for c in rows]
            line, = ax.semilogy(n, worst, "-o", ms=4, label=f"hg={alpha:g} vs={kappa:g}")
            bad = [(a, w) for a, w, c in zip(n, worst, rows) if not (c["stable"] and c["converged"])]
            if bad:
                ax.plot(*zip(*bad), "x", color=line.get_color(), ms=9, mew=2)
        ax.axhline(tol * 100, color="k", ls="--", lw=1)
        d = task["env_default"]
        if d["errors"] is not None:
            ax.plot([d["resolution"] or _resolution(task, d["shape"])], [max(d["errors"].values()) * 100], "s", ms=13,
                    mfc="none", mec="red", mew=2, label="env default")
        for label, marker, colour in (("chosen", "*", "gold"), ("best", "D", "green")):
            c = task[label]
            if c is not None and (label == "chosen" or task["chosen"] is None):
                ax.plot([c["resolution"]], [max(c["errors"].values()) * 100], marker, ms=16, mfc="none", mec=colour,
                        mew=2, label=f"{label}: n={c['resolution']} hg={c['hourglass_control']:g} vs={c['volume_stiffness']:g}")
        ax.set_title(f"{name} (ref {tuple(task['reference_shape'][0])})", fontsize=10)
        ax.set_xlabel("resolution n (elements <= max size / n)")
        ax.set_ylabel("worst error: force, target, volume (%)")
        ax.legend(fontsize=6.5, loc="best")
        ax.grid(alpha=0.3, which="both")
    fig.suptitle("Mass-spring static equilibria against fem-neohookean; x = unstable (saddle) or not converged", fontsize=10)
    fig.tight_layout()
    path = ROOT / "docs" / "figures" / "env_accuracy.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _resolution(task, shape):
    for c in task["candidates"]:
        if list(c["shape"]) == list(shape):
            return c["resolution"]
    return None


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer resolutions and settings")
    run(parser.parse_args().quick)
