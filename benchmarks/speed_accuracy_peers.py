"""Speed against accuracy of a peer engine: MuJoCo's flex on the speed-accuracy chart's scenes.

    python -m benchmarks.speed_accuracy_peers [--resolutions 4 8 12] [--dts 1e-4 2e-4 5e-4 1e-3]

What it measures: the point (wall time per simulated second, node-position error) of MuJoCo's
3-D flex on the scenes of ``benchmarks/speed_accuracy.py`` (its module docstring defines them),
so that the peer can be read against the chart's points (benchmarks/results/speed_accuracy.json).

Scene match. The same 4 cm block (E = 5 kPa, nu = 0.45, rho = 1060 kg/m^3, no gravity) on the same
nodes as the chart's ``block(n)``: every hexahedron is split into 6 tetrahedra (``peers.hex_to_tets``,
Kuhn split, conforming) and written as the MJCF ``flexcomp type="direct"`` of ``peers.mjcf``; the
bottom nodes (y = 0) are pinned. The flex's vertices are bodies with three slide joints (x, y, z),
so a single component can be imposed: before every ``mj_step`` the imposed components of the tool
nodes get the position and velocity of the chart's path (``tool_positions(scene, rest, ramp(t))``
and its time derivative): all three in ``pull``, u_y only in ``indentation`` (x and z stay free: the
chart's frictionless probe). After the last step (t = 1 s) they are set to the path's end and the
final vertex positions are compared, with ``speed_accuracy.field_errors`` at the same 125 material
points, with the chart's reference (the static fem-neohookean equilibrium at n = 20 from
``speed_accuracy.reference_chain`` over n = 8, 12, 16, 20, cached as .npy under --cache).

Differences from the chart (recorded in the JSON as ``deviations``): MuJoCo's own tet elasticity
instead of our models; uniform vertex masses (flexcomp spreads ``mass`` evenly over the vertices);
stiffness-proportional damping with beta = the median damping / stiffness of the chart's ``baudet``
springs at the same n (``damping = peers``, peers.py's rule) and, as a second point, none
(``damping = none``: that explicit damping term is what limits the stable dt, and the ramp is slow
enough for the undamped block to end close to equilibrium); explicit Euler (MuJoCo 4 integrates flex
elasticity explicitly); dt = the largest of ``--dts`` whose 1 s run stays finite without MuJoCo's
bad-QACC reset (a run predicted from the previous dt to exceed ``--budget`` s is not started).

Speed: ``wall_per_sim_s`` = wall seconds of the stepping loop (imposing the tool included) / 1 s
simulated; model compilation excluded (``setup_s``); runs under 1.5 s repeated, median of 3.

Writes benchmarks/results/speed_accuracy_peers.json atomically. Without the ``mujoco`` package
(the ``bench`` extra) it prints a message and exits without writing.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import speed_accuracy as sa
from benchmarks.peers import hex_to_tets, mjcf
from training.common import write_json

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

RESOLUTIONS = (4, 8, 12)
DT_LADDER = (2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3)  # s, ascending
#: damping variants: peers.py's rule, and none (the Rayleigh term is what limits explicit dt)
DAMPINGS = ("peers", "none")
DEFAULT_OUT = HERE / "results" / "speed_accuracy_peers.json"
DEFAULT_CACHE = Path(tempfile.gettempdir()) / "tissue-gym-speed-accuracy-peers"
REFERENCE_CHAIN = (8, 12, 16, 20)
STEP_BUDGET = 60.0  # s of wall time: a run predicted (from the previous dt) to take longer is skipped

SCENE_MATCH = ("same block(n) nodes (hexes Kuhn-split into 6 tets each), same E, nu, density, no gravity, bottom "
               "pinned, same tool nodes and path (smoothstep over 0.5 s, hold to 1 s): pull imposes all three "
               "components, indentation u_y only (x, z free, the frictionless probe); error against the chart's "
               "n=20 fem-neohookean reference at the same 125 material points")
DEVIATIONS = [
    "physics: MuJoCo's built-in dim-3 flex elasticity on linear tets (6 per hex), not a hex model",
    "mass: uniform vertex masses (flexcomp spreads the total mass evenly), not lumped element masses",
    "damping: MuJoCo flex stiffness-proportional damping, beta = median damping/stiffness of the chart's baudet springs "
    "at the same n (peers.py's rule; rows damping=peers), or none (rows damping=none)",
    "integration: MuJoCo explicit Euler (MuJoCo 4 integrates flex elasticity explicitly) at the largest finite, settled "
    "dt of the ladder, not the chart's steppings",
    "indentation: none beyond the above (the flex vertices' slide joints let u_y alone be imposed)",
    "tool: imposed by overwriting the slide joints' qpos/qvel before every step (the tool nodes' own elastic "
    "acceleration within a step is discarded)",
]


def rayleigh_beta(n: int) -> float:
    """peers.py's damping rule on the chart's block: median c / k of the baudet springs (s)."""
    model = sa._mss_model("baudet", n)
    return float(np.median(model.damping / model.stiffness))


class FlexScene:
    """MuJoCo flex model of ``scene`` on block(n); ``run(dt)`` simulates 1 s and returns positions."""

    def __init__(self, mujoco, scene: sa.SceneSpec, n: int, beta: float):
        self.mujoco, self.scene, self.n = mujoco, scene, n
        self.mesh = sa.block(n)
        self.rest = np.asarray(self.mesh.nodes, float)
        self.path = sa.ScenePath(scene, self.mesh)
        self.tets = hex_to_tets(self.rest, self.mesh.elements)
        self.mass = float(sa.DENSITY * sa.SIZE ** 3)
        self.beta = beta
        self.warnings: list[str] = []
        self._previous_handler = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(self.warnings.append)
        start = time.perf_counter()
        self.xml = mjcf(self.rest, self.tets, self.path.bottom, young_modulus=sa.YOUNG, poisson_ratio=sa.POISSON,
                        mass=self.mass, gravity=0.0, dt=DT_LADDER[0], damping=beta)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self.setup_s = time.perf_counter() - start
        m = self.model
        if m.nflexvert != len(self.rest):
            raise RuntimeError(f"flex has {m.nflexvert} vertices, expected {len(self.rest)}")
        mujoco.mj_forward(m, self.data)
        if not np.allclose(self.data.flexvert_xpos, self.rest):
            raise RuntimeError("flex vertices are not in the order of the block's nodes")
        # imposed dofs: the tool vertices' slide joints along the scene's imposed components
        bodies = m.flex_vertbodyid[self.path.tool]
        if np.any(bodies == 0):
            raise RuntimeError("a tool vertex is pinned to the world")
        qpos, qvel = [], []
        for body in bodies:
            adr, num = int(m.body_jntadr[body]), int(m.body_jntnum[body])
            for c in self.path.components:
                joint = next(j for j in range(adr, adr + num)
                             if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE and np.allclose(m.jnt_axis[j], np.eye(3)[c]))
                qpos.append(int(m.jnt_qposadr[joint]))
                qvel.append(int(m.jnt_dofadr[joint]))
        self.qpos_index, self.qvel_index = np.array(qpos), np.array(qvel)
        tool_rest = self.rest[self.path.tool]
        self._tool_rest = tool_rest
        self._rest_imposed = tool_rest[:, self.path.components].ravel()

    def _targets(self, t: float):
        """(imposed displacements, their velocities) at time t, flattened like qpos_index."""
        s, ds_dt = sa.ramp(t), sa.ramp_rate(t)
        comps = self.path.components
        position = sa.tool_positions(self.scene, self._tool_rest, s)[:, comps].ravel()
        eps = 1e-6
        dp_ds = (sa.tool_positions(self.scene, self._tool_rest, s + eps)
                 - sa.tool_positions(self.scene, self._tool_rest, s - eps))[:, comps].ravel() / (2 * eps)
        return position - self._rest_imposed, dp_ds * ds_dt

    def run(self, dt: float) -> dict:
        """Reset, simulate END_TIME s at dt. Returns positions (N, 3) at the end, wall s, steps (planned
        and done: a run stops at MuJoCo's bad-QACC warning), the warning, and the largest speed (m/s)
        of a free dof at the end (a slowly growing instability stays finite: ``settled`` catches it)."""
        mujoco, m, d = self.mujoco, self.model, self.data
        mujoco.mj_resetData(m, d)
        m.opt.timestep = float(dt)
        steps = int(round(sa.END_TIME / dt))
        # the path is precomputed outside the timing (the chart's controls are cheap too); constant in the hold
        hold = self._targets(sa.RAMP_TIME)
        targets = [self._targets(k * dt) if k * dt < sa.RAMP_TIME else hold for k in range(steps + 1)]
        qi, vi = self.qpos_index, self.qvel_index
        warning = d.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)]
        done = steps
        start = time.perf_counter()
        for k in range(steps):
            q, v = targets[k]
            d.qpos[qi] = q
            d.qvel[vi] = v
            mujoco.mj_step(m, d)
            if k & 255 == 255 and warning.number > 0:
                done = k + 1
                break
        d.qpos[qi], d.qvel[vi] = targets[steps]
        mujoco.mj_forward(m, d)
        wall = time.perf_counter() - start
        bad = None
        if warning.number > 0:
            bad = "MuJoCo: " + (self.warnings[-1].strip() if self.warnings else "bad QACC") + " (mjData was reset)"
        free = np.ones(m.nv, bool)
        free[vi] = False
        return dict(positions=np.array(d.flexvert_xpos, float), wall_s=wall, steps=steps, steps_done=done,
                    unstable_reason=bad, final_max_free_speed_m_s=float(np.abs(d.qvel[free]).max()))

    def tool_peak_speed(self) -> float:
        """Largest speed (m/s) of a tool node along the path (the settled test's threshold)."""
        times = np.linspace(0.0, sa.RAMP_TIME, 201)
        speeds = [np.abs(self._targets(t)[1]).max() for t in times]
        return float(max(speeds))

    def close(self):
        self.mujoco.set_mju_user_warning(self._previous_handler)


def reference(scene_name: str, cache: Path, points) -> np.ndarray:
    """(P, 3) displacement of the chart's reference (n = 20 fem-neohookean), cached as .npy."""
    path = cache / f"ref_{scene_name}_n{REFERENCE_CHAIN[-1]}_u.npy"
    if path.exists():
        u = np.load(path)
        if u.shape == points.shape:
            return u
    print(f"{scene_name}: computing the reference chain {REFERENCE_CHAIN} (about a minute)", flush=True)
    chain = sa.reference_chain(sa.SCENES[scene_name], REFERENCE_CHAIN, points)
    u = chain[-1]["u_points"]
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npy")
    np.save(tmp, u)
    tmp.replace(path)
    return u


def measure_point(mujoco, scene_name: str, n: int, ladder, u_ref, points, budget=STEP_BUDGET, damping="peers") -> dict:
    scene = sa.SCENES[scene_name]
    beta = rayleigh_beta(n) if damping == "peers" else 0.0
    flex = FlexScene(mujoco, scene, n, beta)
    row = dict(scene=scene_name, method="mujoco-flex", stepping="explicit Euler", damping=damping, resolution=n,
               n_nodes=int(len(flex.rest)), n_tets=int(len(flex.tets)), rayleigh_beta_s=beta,
               setup_s=flex.setup_s, imposed_components=[int(c) for c in flex.path.components],
               tool_nodes=int(len(flex.path.tool)))
    scan, best = [], None
    threshold = flex.tool_peak_speed()
    row["settled_threshold_m_s"] = threshold
    try:
        for dt in sorted(ladder, reverse=True):  # largest first: the first finite, settled run is the chosen dt
            previous = next((e for e in reversed(scan) if e.get("steps_done")), None)
            predicted = None if previous is None else previous["wall_s"] / previous["steps_done"] * round(sa.END_TIME / dt)
            if predicted is not None and predicted > budget:
                scan.append(dict(dt_s=dt, status="skipped", reason=f"predicted {predicted:.0f} s > {budget:g} s"))
                continue
            run = flex.run(dt)
            u = sa.displacement_at_points(flex.mesh, run.pop("positions"), points)
            entry = dict(dt_s=dt, **run, finite=bool(np.all(np.isfinite(u))))
            entry["settled"] = entry["final_max_free_speed_m_s"] <= threshold
            if entry["finite"] and entry["unstable_reason"] is None:
                entry["error_pct"], entry["error_max_pct"] = sa.field_errors(u, u_ref)
            if entry["finite"] and entry["unstable_reason"] is None and entry["settled"]:
                entry["status"] = "ok"
            elif entry["finite"] and entry["unstable_reason"] is None:
                entry["status"] = "unsettled"
                entry["reason"] = (f"a free node moves at {entry['final_max_free_speed_m_s']:.3g} m/s at t = 1 s, faster "
                                   f"than the tool ever does ({threshold:.3g} m/s): a slowly growing instability")
            else:
                entry["status"] = "unstable"
                entry["reason"] = entry["unstable_reason"] or "non-finite positions"
            scan.append(entry)
            print(f"  {scene_name:11s} {damping:5s} n={n:2d} dt={dt * 1e3:6.3g} ms {entry['status']:9s} wall {entry['wall_s']:7.2f} s"
                  + (f"  error {entry['error_pct']:.3f}% (max {entry['error_max_pct']:.3f}%)" if "error_pct" in entry else "")
                  + f"  max|v| {entry['final_max_free_speed_m_s']:.3g} m/s" + ("" if entry["status"] == "ok" else f"  {entry['reason'][:60]}"),
                  flush=True)
            if entry["status"] == "ok":
                best = entry
                break
        if best is None:
            skipped = any(e["status"] == "skipped" for e in scan)
            row.update(status="over budget" if skipped else "unstable", dt_scan=scan,
                       reason=("no dt of the ladder gave a finite, settled run"
                               + (f" within the {budget:g} s budget" if skipped else "")))
            return row
        walls = [best["wall_s"]]
        if best["wall_s"] < sa.REPEAT_BELOW:
            for _ in range(sa.REPEATS - 1):
                walls.append(flex.run(best["dt_s"])["wall_s"])
        wall = float(np.median(walls))
        row.update(status="ok", dt_s=best["dt_s"], steps=best["steps"], sim_time_s=best["steps"] * best["dt_s"],
                   wall_s=wall, repeats=len(walls), wall_samples_s=walls, wall_per_sim_s=wall / sa.END_TIME,
                   error_pct=best["error_pct"], error_max_pct=best["error_max_pct"], dt_scan=scan)
        return row
    finally:
        flex.close()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=list(RESOLUTIONS))
    parser.add_argument("--scenes", nargs="+", default=list(sa.SCENES), choices=list(sa.SCENES))
    parser.add_argument("--dts", type=float, nargs="+", default=list(DT_LADDER), help="dt ladder (s)")
    parser.add_argument("--dampings", nargs="+", default=list(DAMPINGS), choices=list(DAMPINGS))
    parser.add_argument("--budget", type=float, default=STEP_BUDGET, help="wall s cap per run (predicted)")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE, help="directory of the cached references")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    try:
        import mujoco
    except ImportError as error:
        print(f"skipped: package 'mujoco' not installed ({error}); pip install -e '.[bench]'")
        return None
    points = sa.material_points()
    rows, scenes = [], {}
    start = time.perf_counter()
    for name in args.scenes:
        u_ref = reference(name, args.cache, points)
        scenes[name] = dict(label=sa.SCENES[name].label,
                            reference=dict(resolution=REFERENCE_CHAIN[-1], chain=list(REFERENCE_CHAIN),
                                           method="speed_accuracy.reference_chain (fem-neohookean, static)",
                                           max_displacement_m=float(np.linalg.norm(u_ref, axis=1).max())))
        for n in args.resolutions:
            for damping in args.dampings:
                rows.append(measure_point(mujoco, name, n, args.dts, u_ref, points, args.budget, damping))
    deviations = list(DEVIATIONS)
    summary = dict(method="mujoco-flex", mujoco_version=mujoco.__version__, scene_match=SCENE_MATCH,
                   deviations=deviations, error_definition=sa.ERROR_DEFINITION,
                   speed_definition=sa.SPEED_DEFINITION + "; the per-step tool update in Python is included",
                   dt_ladder_s=sorted(args.dts), dt_rule="largest dt of the ladder whose 1 s run is finite, without "
                   "MuJoCo's bad-QACC reset, and settled (at t = 1 s no free dof faster than the tool's peak speed)", repeats_below_s=sa.REPEAT_BELOW, repeats=sa.REPEATS,
                   block=dict(size_m=sa.SIZE, young_modulus_pa=sa.YOUNG, poisson_ratio=sa.POISSON,
                              density_kg_m3=sa.DENSITY, gravity=0.0),
                   machine=dict(platform=platform.platform(), processor=platform.processor() or platform.machine(),
                                python=platform.python_version(), numpy=np.__version__),
                   scenes=scenes, rows=rows, total_wall_s=time.perf_counter() - start)
    write_json(args.out, summary, indent=1, default=lambda v: None if v is None else float(v))
    print(f"\n{'scene':11s} {'damp':5s} {'n':>3s} {'dt ms':>6s} {'wall/sim s':>10s} {'error %':>8s} {'max %':>7s}")
    for r in rows:
        if r["status"] == "ok":
            print(f"{r['scene']:11s} {r['damping']:5s} {r['resolution']:3d} {r['dt_s'] * 1e3:6.3g} {r['wall_per_sim_s']:10.3f} "
                  f"{r['error_pct']:8.3f} {r['error_max_pct']:7.3f}")
        else:
            print(f"{r['scene']:11s} {r['damping']:5s} {r['resolution']:3d} {r['status']}: {r.get('reason', '')}")
    print(f"written to {args.out}")
    return summary


if __name__ == "__main__":
    main()
