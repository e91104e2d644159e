"""Step speed of our model next to MuJoCo's flex and PyBullet's neo-Hookean soft body, one run.

    python -m benchmarks.peers [--rounds 7] [--steps 100] [--no-static]

Scene (the same physical block in every engine, ``sim_core.studies.bench``'s): 10 x 10 x 10 cubes
of 0.1 m (1331 nodes), E = 1e4 Pa, nu = 0.3, rho = 1500 kg/m^3, bottom face (y = 0) fixed, the reduced
gravity 0.5 m/s^2 along -y (a few % strain), dt = 1 ms. Our model runs with the environments'
hourglass_control = 0.5 (without it the self-weight compression buckles a zero-energy mode after
about 5 s). The peers get the same nodes: each hex is
split into 6 tetrahedra (Kuhn split, conforming), written as an MJCF ``flexcomp type="direct"``
for MuJoCo and a legacy VTK file for PyBullet. Their stiffness-proportional (Rayleigh) damping is
set to the median of our springs' damping / stiffness, so the three damp alike.

Measured, interleaved (the machine is shared, so engines take turns within every round): median
ms per step over ``--rounds`` blocks of ``--steps`` steps, after a 1 s run from rest that also
gives the sanity check (mean y displacement of the top face after 1 s, finite or not).
"At equal stability": our explicit Euler at 0.9 x ``stable_time_step``; our implicit Euler and the
peers at the largest dt of a fixed ladder whose 1 s run stays finite and stable with a top sag
within 10% of the same engine at 1 ms; reported as simulated seconds per wall second.

Writes benchmarks/results/peers.json atomically. An engine whose package is missing is skipped
with a message; one that fails to build the scene is recorded with its error string.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from training.common import write_json
from sim_core.solvers.integrators import ImplicitEuler, SymplecticEuler, stable_time_step
from sim_core.models.material import Material
from sim_core.geometry.mesh import LOCAL_CORNERS, HexMesh
from sim_core.models.model import build_model

SCENE = dict(shape=(10, 10, 10), spacing=0.1, young_modulus=1e4, poisson_ratio=0.3, density=1500.0,
             gravity=0.5, duration=1.0, hourglass_control=0.5)
DT = 1e-3
#: dt ladder (s) for "largest stable dt" of the implicit and peer integrators.
DT_LADDER = (2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 1e-1)
SAG_TOLERANCE = 0.10
#: simulated time (s) of the settling run at each engine's equal-stability dt, compared with statics
SETTLE_TIME = 10.0
DEFAULT_OUT = Path(__file__).parent / "results" / "peers.json"


# -- geometry shared by every engine -------------------------------------------------------------
def _kuhn_corners() -> np.ndarray:
    """(6, 4) local hex corners (VTK order) of the 6 tets around the diagonal 0 -> 6."""
    lookup = {tuple(c): i for i, c in enumerate(LOCAL_CORNERS.astype(int).tolist())}
    tets = []
    for order in itertools.permutations(range(3)):
        corner = [0, 0, 0]
        path = [lookup[tuple(corner)]]
        for axis in order:
            corner[axis] = 1
            path.append(lookup[tuple(corner)])
        tets.append(path)
    return np.array(tets)


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) signed volumes in m^3 (positive when 1-2-3 turn counter-clockwise seen from 0... 3)."""
    a, b, c, d = (nodes[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def hex_to_tets(nodes: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """Split each hexahedron (VTK order) into 6 tetrahedra sharing its 0-6 diagonal.

    Every hex uses the same diagonal direction, so neighbouring faces are cut along the same face
    diagonal (conforming). Tets are reordered to positive volume. Returns (6 M, 4) node indices.
    """
    tets = np.asarray(elements)[:, _kuhn_corners()].reshape(-1, 4).copy()
    negative = tet_volumes(nodes, tets) < 0
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return tets


def write_vtk(path, nodes: np.ndarray, tets: np.ndarray) -> Path:
    """Legacy ASCII VTK unstructured grid of tetrahedra (what PyBullet's loadSoftBody reads)."""
    path = Path(path)
    with open(path, "w") as f:
        f.write("# vtk DataFile Version 2.0\ntissue-gym block\nASCII\nDATASET UNSTRUCTURED_GRID\n")
        f.write(f"POINTS {len(nodes)} double\n")
        f.writelines(f"{x:.12g} {y:.12g} {z:.12g}\n" for x, y, z in nodes)
        f.write(f"CELLS {len(tets)} {5 * len(tets)}\n")
        f.writelines(f"4 {a} {b} {c} {d}\n" for a, b, c, d in tets)
        f.write(f"CELL_TYPES {len(tets)}\n")
        f.write("10\n" * len(tets))
    return path


def mjcf(nodes, tets, pinned, *, young_modulus, poisson_ratio, mass, gravity, dt, damping) -> str:
    """MJCF of one 3-D flex on exactly these nodes and tets, ``pinned`` nodes fixed to the world.

    Explicit Euler: MuJoCo 4 no longer integrates flex elasticity implicitly under 'implicit' or
    'implicitfast'. Contacts are off (a lone block under gravity)."""
    point = " ".join(f"{v:.12g}" for v in np.asarray(nodes, float).ravel())
    element = " ".join(str(int(i)) for i in np.asarray(tets).ravel())
    pin = " ".join(str(int(i)) for i in pinned)
    return f"""<mujoco model="tissue-gym block">
  <option timestep="{dt:.9g}" gravity="0 {-gravity:.9g} 0" integrator="Euler"/>
  <worldbody>
    <flexcomp name="block" type="direct" dim="3" radius="0.001" mass="{mass:.12g}"
              point="{point}" element="{element}">
      <contact contype="0" conaffinity="0" selfcollide="none"/>
      <edge equality="false"/>
      <elasticity young="{young_modulus:.9g}" poisson="{poisson_ratio:.9g}" damping="{damping:.9g}"/>
      <pin id="{pin}"/>
    </flexcomp>
  </worldbody>
</mujoco>
"""


def machine() -> dict:
    """Same description as ``sim_core.studies.bench.measure`` writes into step_speed.json."""
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__}


class Scene:
    """The block, its tets, fixed and top nodes, and our model (for the damping and references)."""

    def __init__(self, shape=SCENE["shape"], spacing=SCENE["spacing"], young_modulus=SCENE["young_modulus"],
                 poisson_ratio=SCENE["poisson_ratio"], density=SCENE["density"], gravity=SCENE["gravity"],
                 hourglass_control=SCENE["hourglass_control"]):
        self.mesh = HexMesh.block(shape, spacing)
        self.material = Material(young_modulus, poisson_ratio, density)
        self.young_modulus, self.poisson_ratio, self.density, self.gravity = (
            float(young_modulus), float(poisson_ratio), float(density), float(gravity))
        self.nodes = np.asarray(self.mesh.nodes, float)
        self.tets = hex_to_tets(self.nodes, self.mesh.elements)
        height = self.nodes[:, 1]
        self.bottom = np.flatnonzero(np.isclose(height, height.min()))
        self.top = np.flatnonzero(np.isclose(height, height.max()))
        self.mass = float(density * self.mesh.element_volumes().sum())
        # hourglass control as in the environments: without it the block, compressed by its own
        # weight, buckles into a zero-energy mode after about 5 s (measured; explicit then diverges)
        self.hourglass_control = float(hourglass_control)
        self.model = build_model(self.mesh, self.material, gravity=(0.0, -self.gravity, 0.0),
                                 hourglass_control=self.hourglass_control)
        self.control = self.model.new_control()
        self.control.impose(self.bottom, self.nodes[self.bottom])
        #: our per-spring damping c = 2 sqrt(mu k) is stiffness-proportional with beta = c / k (s)
        self.rayleigh_beta = float(np.median(self.model.damping / self.model.stiffness))

    def describe(self) -> dict:
        return {"shape": [int(n) for n in self.mesh.shape], "spacing_m": float(self.mesh.spacing[0]),
                "nodes": int(self.mesh.n_nodes), "hexahedra": int(self.mesh.n_elements), "tets": int(len(self.tets)),
                "young_modulus_pa": self.young_modulus, "poisson_ratio": self.poisson_ratio,
                "density_kg_m3": self.density, "mass_kg": self.mass, "gravity_m_s2": [0.0, -self.gravity, 0.0],
                "fixed_nodes": int(len(self.bottom)), "top_nodes": int(len(self.top)),
                "rayleigh_beta_s": self.rayleigh_beta, "ours_hourglass_control": self.hourglass_control}

    def sag(self, positions) -> float:
        return float(np.mean(np.asarray(positions)[self.top, 1] - self.nodes[self.top, 1]))


@contextlib.contextmanager
def quiet_stdout():
    """Silence C-level prints (PyBullet's loader prints to fd 1)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)


# -- engines: step(n), positions(), set_dt(dt), reset() ------------------------------------------
class Ours:
    def __init__(self, scene: Scene, integrator: str, dt: float = DT):
        self.scene, self.kind, self.dt = scene, integrator, float(dt)
        self.name = f"ours-{integrator}"
        self.physics = (f"Baudet hex mass-spring + corrections + volume forces + hourglass control {scene.hourglass_control:g}, "
                        + ("symplectic Euler" if integrator == "explicit" else "linearised implicit Euler (BiCGSTAB)"))
        self.version = "tissue-gym (this repo)"
        self.reset()

    def reset(self):
        self.integrator = SymplecticEuler() if self.kind == "explicit" else ImplicitEuler()
        self.state = self.scene.model.new_state()
        self.scratch = self.state.copy()
        self.unstable_reason = None

    def set_dt(self, dt):
        self.dt = float(dt)

    def step(self, n: int):
        model, control = self.scene.model, self.scene.control
        for _ in range(n):
            report = self.integrator.simulate(model, self.state, self.scratch, self.dt, control)
            self.state, self.scratch = self.scratch, self.state
            if report.unstable and self.unstable_reason is None:
                self.unstable_reason = report.unstable_reason

    def positions(self):
        return self.state.positions


class MuJoCoFlex:
    name = "mujoco-flex"

    def __init__(self, scene: Scene, dt: float = DT):
        import mujoco

        self.mujoco, self.scene = mujoco, scene
        self.version = mujoco.__version__
        # collect MuJoCo's warnings instead of letting it write MUJOCO_LOG.TXT into the cwd
        self.warnings: list[str] = []
        self._previous_handler = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(self.warnings.append)
        self.physics = "MuJoCo flex (dim 3, linear-elastic tets), explicit Euler, Rayleigh damping"
        self.xml = mjcf(scene.nodes, scene.tets, scene.bottom, young_modulus=scene.young_modulus,
                        poisson_ratio=scene.poisson_ratio, mass=scene.mass, gravity=scene.gravity, dt=dt,
                        damping=scene.rayleigh_beta)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        if self.model.nflexvert != len(scene.nodes):
            raise RuntimeError(f"flex has {self.model.nflexvert} vertices, expected {len(scene.nodes)}")
        self.unstable_reason = None
        self.reset()
        if not np.allclose(self.positions(), scene.nodes):
            raise RuntimeError("flex vertices are not in the order of the scene nodes")

    def reset(self):
        self.mujoco.mj_resetData(self.model, self.data)
        self.mujoco.mj_forward(self.model, self.data)
        self.unstable_reason = None

    def set_dt(self, dt):
        self.model.opt.timestep = float(dt)

    def step(self, n: int):
        self.mujoco.mj_step(self.model, self.data, nstep=int(n))
        # MuJoCo resets mjData after a bad acceleration, so finite positions can hide a divergence
        bad = self.data.warning[int(self.mujoco.mjtWarning.mjWARN_BADQACC)]
        if bad.number > 0 and self.unstable_reason is None:
            message = self.warnings[-1].strip() if self.warnings else "bad QACC warning"
            self.unstable_reason = f"MuJoCo: {message} (mjData was reset)"

    def close(self):
        self.mujoco.set_mju_user_warning(self._previous_handler)

    def positions(self):
        return self.data.flexvert_xpos


class PyBulletNeoHookean:
    name = "pybullet-neohookean"

    def __init__(self, scene: Scene, dt: float = DT, workdir=None):
        import tempfile

        import pybullet

        self.p, self.scene, self.dt = pybullet, scene, float(dt)
        self.version = _dist_version("pybullet")
        self.physics = "PyBullet deformable (neo-Hookean tets, implicit solver), uniform node masses"
        self._tmp = tempfile.TemporaryDirectory(prefix="tissue-gym-peers-") if workdir is None else None
        self.vtk = write_vtk(Path(workdir or self._tmp.name) / "block.vtk", scene.nodes, scene.tets)
        e, nu = scene.young_modulus, scene.poisson_ratio
        self.mu, self.lam = e / (2 * (1 + nu)), e * nu / ((1 + nu) * (1 - 2 * nu))
        with quiet_stdout():
            self.client = pybullet.connect(pybullet.DIRECT)
        self.reset()

    def reset(self):
        p, c = self.p, self.client
        with quiet_stdout():
            p.resetSimulation(p.RESET_USE_DEFORMABLE_WORLD, physicsClientId=c)
            p.setGravity(0, -self.scene.gravity, 0, physicsClientId=c)
            p.setTimeStep(self.dt, physicsClientId=c)
            self.body = p.loadSoftBody(str(self.vtk), basePosition=[0, 0, 0], scale=1.0, mass=self.scene.mass,
                                       useNeoHookean=1, NeoHookeanMu=self.mu, NeoHookeanLambda=self.lam,
                                       NeoHookeanDamping=self.scene.rayleigh_beta, useSelfCollision=0,
                                       collisionMargin=0.001, frictionCoeff=0.5, physicsClientId=c)
        if self.body < 0:
            raise RuntimeError(f"loadSoftBody failed for {self.vtk}")
        rest = self.positions()
        if rest.shape != self.scene.nodes.shape or not np.allclose(rest, self.scene.nodes, atol=1e-6):
            raise RuntimeError(f"soft body has {len(rest)} nodes not matching the scene's {len(self.scene.nodes)}")
        for node in self.scene.bottom:
            p.createSoftBodyAnchor(self.body, int(node), -1, -1, physicsClientId=c)
        self.unstable_reason = None

    def set_dt(self, dt):
        self.dt = float(dt)
        self.p.setTimeStep(self.dt, physicsClientId=self.client)

    def step(self, n: int):
        for _ in range(int(n)):
            self.p.stepSimulation(physicsClientId=self.client)

    def positions(self):
        _, points = self.p.getMeshData(self.body, -1, flags=self.p.MESH_DATA_SIMULATION_MESH,
                                       physicsClientId=self.client)
        return np.asarray(points, float)

    def close(self):
        with contextlib.suppress(Exception):
            self.p.disconnect(physicsClientId=self.client)
        if self._tmp is not None:
            self._tmp.cleanup()


def _dist_version(name: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return "unknown"


# -- measurements --------------------------------------------------------------------------------
def simulate_from_rest(engine, scene: Scene, dt: float, duration: float) -> dict:
    """Reset, run ``duration`` s at ``dt``; top sag, finiteness, instability, wall time."""
    engine.reset()
    engine.set_dt(dt)
    steps = max(int(round(duration / dt)), 1)
    start = time.perf_counter()
    engine.step(steps)
    wall = time.perf_counter() - start
    positions = np.asarray(engine.positions(), float)
    finite = bool(np.all(np.isfinite(positions)))
    return {"dt_s": float(dt), "steps": steps, "sim_time_s": steps * dt, "wall_s": wall,
            "top_sag_m": scene.sag(positions) if finite else None, "finite": finite,
            "unstable_reason": engine.unstable_reason}


def interleaved_ms(engines: dict, steps: dict, rounds: int) -> dict:
    """Median ms per step of each engine, all engines taking turns in every round (order rotated)."""
    names = list(engines)
    samples = {name: [] for name in names}
    for r in range(rounds):
        for name in names[r % len(names):] + names[:r % len(names)]:
            start = time.perf_counter()
            engines[name].step(steps[name])
            samples[name].append((time.perf_counter() - start) * 1e3 / steps[name])
    return {name: (float(np.median(s)), [round(v, 5) for v in s]) for name, s in samples.items()}


def passes(run: dict, reference: dict) -> bool:
    if not run["finite"] or run["unstable_reason"] or reference["top_sag_m"] is None:
        return False
    return abs(run["top_sag_m"] - reference["top_sag_m"]) <= SAG_TOLERANCE * abs(reference["top_sag_m"])


def build_engines(scene: Scene, only=None):
    """name -> engine, plus name -> record for engines skipped or failed."""
    factories = {
        "ours-explicit": lambda: Ours(scene, "explicit"),
        "ours-implicit": lambda: Ours(scene, "implicit"),
        "mujoco-flex": lambda: MuJoCoFlex(scene),
        "pybullet-neohookean": lambda: PyBulletNeoHookean(scene),
    }
    packages = {"mujoco-flex": "mujoco", "pybullet-neohookean": "pybullet"}
    engines, records = {}, {}
    for name, factory in factories.items():
        if only and name not in only:
            continue
        try:
            engines[name] = factory()
        except ImportError as error:
            message = f"skipped: package {packages.get(name, '?')!r} not installed ({error})"
            print(f"{name}: {message}")
            records[name] = {"status": "skipped", "error": message}
        except Exception as error:  # a peer that cannot build the scene is a result, not a crash
            message = f"{type(error).__name__}: {error}"
            print(f"{name}: failed to build the scene: {message}")
            records[name] = {"status": "error", "error": message}
    return engines, records


def measure(rounds: int = 7, steps: int = 100, static: bool = True, only=None, scene: Scene | None = None) -> dict:
    scene = Scene() if scene is None else scene
    engines, records = build_engines(scene, only)
    results = _header(scene, rounds, steps)
    for name, engine in engines.items():
        results["engines"][name] = {"status": "ok", "version": engine.version, "physics": engine.physics}
    results["engines"].update(records)
    sanity = _sanity(engines, scene, results)
    # 2. speed at dt = 1 ms, interleaved, continuing from the loaded, moving state
    timing = interleaved_ms(engines, {name: steps for name in engines}, rounds)
    for name, (ms, samples) in timing.items():
        results["engines"][name].update(dt_s=DT, ms_per_step=ms, steps_per_s=1e3 / ms,
                                        sim_s_per_wall_s=DT / (ms * 1e-3), ms_per_step_samples=samples)
    _equal_stability(engines, scene, sanity, steps, rounds, results)
    for engine in engines.values():
        if hasattr(engine, "close"):
            engine.close()
    if static:
        results["static_reference"] = _static_reference(scene)
    return results


def _header(scene, rounds, steps):
    """``measure``'s results before any run: the scene, the machine, the versions and the method."""
    duration = SCENE["duration"]
    return {"scene": scene.describe(), "machine": machine(),
            "versions": {"numpy": np.__version__, "mujoco": _dist_version("mujoco"),
                         "pybullet": _dist_version("pybullet"), "numba": _dist_version("numba"),
                         "scipy": _dist_version("scipy")},
            "method": {"dt_s": DT, "rounds": rounds, "steps_per_round": steps, "statistic": "median",
                       "interleaved": True, "sag": f"mean y displacement of the top face after {duration} s from rest",
                       "settled_sag": f"the same after {SETTLE_TIME} s at the equal-stability dt",
                       "equal_stability": ("explicit: 0.9 x stable_time_step; others: largest dt of "
                                           f"{list(DT_LADDER)} s whose {duration} s run is finite, stable and "
                                           f"within {SAG_TOLERANCE:.0%} of the same engine's 1 ms sag")},
            "engines": {}}


def _sanity(engines, scene, results):
    """1. sanity: 1 s from rest at 1 ms (also the warm-up: numba compilation, caches). Returns
    {name: run}; an engine that raises is recorded as an error and dropped from ``engines``."""
    duration = SCENE["duration"]
    sanity = {}
    for name, engine in list(engines.items()):
        try:
            sanity[name] = simulate_from_rest(engine, scene, DT, duration)
        except Exception as error:
            results["engines"][name] = {"status": "error", "error": f"{type(error).__name__}: {error}"}
            engines.pop(name)
            continue
        entry = results["engines"][name]
        entry.update(top_sag_1s_m=sanity[name]["top_sag_m"], finite=sanity[name]["finite"],
                     unstable_reason=sanity[name]["unstable_reason"])
        if not sanity[name]["finite"]:
            print(f"WARNING: {name} gave non-finite positions after {duration} s")
    return sanity


def _equal_stability(engines, scene, sanity, steps, rounds, results):
    """3. at equal stability: each integrator at its largest usable dt (``_largest_usable_dt``), its
    sag settled there, then timed interleaved from a loaded, moving state."""
    chosen = {}
    for name, engine in engines.items():
        if not sanity[name]["finite"]:
            continue
        chosen[name] = _largest_usable_dt(name, engine, scene, sanity[name])
        settled = simulate_from_rest(engine, scene, chosen[name]["dt_s"], SETTLE_TIME)
        chosen[name]["settled"] = settled
        results["engines"][name].update(top_sag_settled_m=settled["top_sag_m"], settled_finite=settled["finite"],
                                        settled_unstable_reason=settled["unstable_reason"])
    stable_engines = {name: engines[name] for name in chosen}
    for name, engine in stable_engines.items():
        engine.reset()
        engine.set_dt(chosen[name]["dt_s"])
        engine.step(max(int(round(0.2 / chosen[name]["dt_s"])), 1))  # a loaded, moving state
    # fewer steps per round at large dt (each is slower), at least 5
    block = {name: max(5, min(steps, int(round(steps * DT / chosen[name]["dt_s"])))) for name in stable_engines}
    timing = interleaved_ms(stable_engines, block, rounds)
    for name, (ms, samples) in timing.items():
        entry = chosen[name]
        entry.update(ms_per_step=ms, steps_per_s=1e3 / ms, sim_s_per_wall_s=entry["dt_s"] / (ms * 1e-3),
                     ms_per_step_samples=samples)
        results["engines"][name]["equal_stability"] = entry


def _largest_usable_dt(name, engine, scene, sanity):
    """The equal-stability dt of one engine, with the runs that chose it ("scan"): 0.9 x
    ``stable_time_step`` for our explicit integrator, else the largest dt of ``DT_LADDER`` whose run
    ``passes`` against the engine's 1 ms ``sanity`` run (the ladder stops at the first failure)."""
    duration = SCENE["duration"]
    ladder = []
    if name == "ours-explicit":
        limit = stable_time_step(scene.model, scene.control)
        dt = 0.9 * limit
        run = simulate_from_rest(engine, scene, dt, duration)
        run["passes"] = passes(run, sanity)
        ladder.append(run)
        chosen = {"dt_s": dt, "stable_time_step_s": limit, "rule": "0.9 x stable_time_step"}
        if not (run["finite"] and run["unstable_reason"] is None):
            chosen["warning"] = "unstable at 0.9 x stable_time_step"
    else:
        best = DT
        for dt in DT_LADDER:
            run = simulate_from_rest(engine, scene, dt, duration)
            run["passes"] = passes(run, sanity)
            ladder.append(run)
            if not run["passes"]:
                break
            best = dt
        chosen = {"dt_s": best, "rule": "largest passing dt of the ladder"}
    chosen["scan"] = ladder
    return chosen


def _static_reference(scene):
    """4. static references on the same nodes: our model and hexahedral neo-Hookean FEM (top sag, m;
    None where a solve did not converge)."""
    from sim_core.solvers.hyperelastic import NeoHookeanFEM
    from sim_core.solvers.static import solve_static

    gravity = (0.0, -scene.gravity, 0.0)
    reference = {}
    try:
        ours = solve_static(scene.model, scene.control)
        reference["ours_static_top_sag_m"] = scene.sag(ours.positions) if ours.converged else None
        fem = NeoHookeanFEM(scene.mesh, scene.material).solve(scene.control, gravity)
        reference["neohookean_hex_fem_static_top_sag_m"] = scene.sag(fem.positions) if fem.converged else None
    except Exception as error:
        reference["error"] = f"{type(error).__name__}: {error}"
    return reference


def _fmt(value, spec):
    return "-" if value is None else format(value, spec)


def table(results: dict) -> str:
    lines = [f"{'engine':<21} {'dt ms':>6} {'ms/step':>8} {'steps/s':>8} {'sim s/wall s':>12} {'sag 1 s mm':>10}"
             f"   | equal stability: {'dt ms':>6} {'ms/step':>8} {'sim s/wall s':>12} {'sag 1 s mm':>10}"
             f" {'settled mm':>10}"]
    for name, e in results["engines"].items():
        if e.get("status") != "ok":
            lines.append(f"{name:<21} {e.get('status')}: {e.get('error')}")
            continue
        sag = None if e.get("top_sag_1s_m") is None else e["top_sag_1s_m"] * 1e3
        flag = "" if e.get("finite", True) and e.get("settled_finite", True) else "  NON-FINITE"
        if e.get("unstable_reason") or e.get("settled_unstable_reason"):
            flag += "  UNSTABLE"
        line = (f"{name:<21} {e['dt_s'] * 1e3:>6.3g} {_fmt(e.get('ms_per_step'), '8.3f')} "
                f"{_fmt(e.get('steps_per_s'), '8.0f')} {_fmt(e.get('sim_s_per_wall_s'), '12.3f')} {_fmt(sag, '10.2f')}")
        s = e.get("equal_stability")
        if s:
            chosen = next((r for r in s["scan"] if abs(r["dt_s"] - s["dt_s"]) < 1e-12), None)
            s_sag = None if chosen is None or chosen["top_sag_m"] is None else chosen["top_sag_m"] * 1e3
            line += (f"   | {'':17} {s['dt_s'] * 1e3:>6.3g} {s['ms_per_step']:>8.3f} {s['sim_s_per_wall_s']:>12.3f} "
                     f"{_fmt(s_sag, '10.2f')}")
            settled = e.get("top_sag_settled_m")
            line += f" {_fmt(None if settled is None else settled * 1e3, '10.2f')}"
        lines.append(line + flag)
    ref = results.get("static_reference", {})
    if ref:
        parts = [f"{k.replace('_top_sag_m', '')} {v * 1e3:.2f} mm" for k, v in ref.items() if isinstance(v, float)]
        lines.append("static top sag: " + ", ".join(parts) + (f" ({ref['error']})" if "error" in ref else ""))
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--steps", type=int, default=100, help="steps per engine per round at dt = 1 ms")
    parser.add_argument("--no-static", action="store_true", help="skip the static reference solves")
    parser.add_argument("--only", nargs="*", help="engine names to run (default: all)")
    parser.add_argument("--out", default=str(DEFAULT_OUT))
    args = parser.parse_args(argv)
    results = measure(args.rounds, args.steps, static=not args.no_static, only=args.only)
    path = Path(args.out)
    write_json(path, results)
    print(table(results))
    print(f"written to {path}")


if __name__ == "__main__":
    main()
