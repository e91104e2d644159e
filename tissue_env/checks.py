"""The task keywords' checks: each returns the checked value or raises a ValueError that names
the keyword, what it got and what is allowed (``TissueEnv`` and every task use them). SI units."""

from __future__ import annotations

import warnings

import numpy as np


#: The tissue models a task can simulate (``sim_core.build_model``'s ``model``): Baudet's springs with
#: small-strain corrections, volume forces and hourglass control, or the finite-strain neo-Hookean
#: stress correction on Baudet-style springs (docs/physics.md section 11).
MODELS = ("baudet", "baudet-hyperelastic")
#: The defaults of ``hourglass_control`` and ``volume_stiffness`` per model: (alpha, kappa multiplier);
#: None where the keyword does not apply ("baudet-hyperelastic": its springs resist the hourglass
#: modes, its ln J pressure holds the volume).
MODEL_DEFAULTS = {"baudet": (1.0, 100.0), "baudet-hyperelastic": (None, None)}
# -- argument checks (ValueError naming the keyword) -------------------------------------------
def _number(name, value, unit=""):
    try:
        return float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number{unit and ' in ' + unit}, got {value!r}") from error


def positive_scalar(name, value, unit=""):
    value = _number(name, value, unit)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0{unit and ' ' + unit}, got {value!r}")
    return value


def nonnegative_scalar(name, value):
    value = _number(name, value)
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return value


def check_damping(damping_ratio, damping_frequency, integrator, integrator_scheme, schemes):
    """The tissue's damping law (``damping_ratio`` None or >= 0, ``damping_frequency`` Hz > 0 or a pair
    f1 < f2: sim_core's ``Material``) and the implicit integrator's time scheme (one of ``schemes``),
    checked with the integrator they need: (damping_ratio, damping_frequency, integrator_scheme)."""
    if damping_ratio is not None:
        damping_ratio = nonnegative_scalar("damping_ratio", damping_ratio)
    if np.ndim(damping_frequency) == 0:
        damping_frequency = positive_scalar("damping_frequency", damping_frequency, "Hz")
    else:
        pair = check_range("damping_frequency", damping_frequency, lambda n, v: positive_scalar(n, v, "Hz"))
        if pair[0] == pair[1]:
            raise ValueError(f"damping_frequency (f1, f2) must have f1 < f2, got {damping_frequency!r}")
        damping_frequency = pair
    if damping_ratio is not None and integrator == "explicit":
        raise ValueError("damping_ratio (a damping law) needs integrator='implicit' or 'static'; the explicit "
                         "integrator takes none")
    if integrator_scheme not in schemes:
        raise ValueError(f"integrator_scheme must be one of {schemes}, got {integrator_scheme!r}")
    if integrator_scheme != "euler" and integrator != "implicit":
        raise ValueError(f"integrator_scheme={integrator_scheme!r} is a scheme of integrator='implicit', got "
                         f"integrator={integrator!r}")
    return damping_ratio, damping_frequency, integrator_scheme


def check_poisson_ratio(name, value):
    value = _number(name, value)
    if not (-0.25 < value < 0.5):
        raise ValueError(f"{name} must lie in (-0.25, 0.5) for the mass-spring model, got {value!r}")
    return value


def check_region(name, value, axes):
    """((a0, b0, ...), (a1, b1, ...)) fractions in [0, 1] of the block along ``axes`` (e.g. "xz"),
    low <= high, as a (2, len(axes)) array; else ValueError naming ``name``."""
    form = "(" + ", ".join("(" + ", ".join(f"{axis}{i}" for axis in axes) + ")" for i in (0, 1)) + ")"
    try:
        region = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be {form} fractions, got {value!r}") from error
    if region.shape != (2, len(axes)) or not np.all(np.isfinite(region)) or np.any(region < 0) or np.any(region > 1) \
            or np.any(region[0] > region[1]):
        raise ValueError(f"{name} must be {form} fractions in [0, 1] with low <= high, got {value!r}")
    return region


def check_range(name, value, check):
    """None or a (low, high) pair whose ends pass ``check`` and low <= high."""
    if value is None:
        return None
    try:
        low, high = value
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be None or a (low, high) pair, got {value!r}") from error
    low, high = check(name, low), check(name, high)
    if low > high:
        raise ValueError(f"{name} must have low <= high, got {value!r}")
    return (low, high)


def check_vector(name, value, unit="m"):
    """A positive scalar (broadcast) or three positive numbers."""
    try:
        array = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number or three numbers in {unit}, got {value!r}") from error
    if not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise ValueError(f"{name} must be finite and > 0 {unit} along every axis, got {value!r}")
    return array


def check_vector_range(name, value, unit="m"):
    """None or a (low, high) pair of ``check_vector`` values (a number or three each, ``unit``) with
    low <= high along every axis, as a pair of (3,) arrays."""
    if value is None:
        return None
    try:
        low, high = value
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be None or a (low, high) pair of sizes in {unit} (a number or three each), "
                         f"got {value!r}") from error
    low, high = check_vector(name, low, unit), check_vector(name, high, unit)
    if np.any(low > high):
        raise ValueError(f"{name} must have low <= high along every axis, got {value!r}")
    return (low, high)


#: The difficulty levels of every task (``difficulty`` keyword; each task's ``DIFFICULTY`` table).
DIFFICULTIES = ("easy", "default", "hard")


def difficulty_settings(table, difficulty, given):
    """The keywords a task's ``difficulty`` sets: ``table[difficulty]`` (the task's ``DIFFICULTY``:
    level -> keyword -> value, defined once per task), with each keyword of ``given`` that was
    passed explicitly (not None) in place of the table's; ValueError for an unknown level. The
    values are then checked by the task's own keyword checks."""
    if not isinstance(difficulty, str) or difficulty not in table:
        raise ValueError(f"difficulty must be one of {tuple(table)}, got {difficulty!r}")
    settings = dict(table[difficulty])
    settings.update({name: value for name, value in given.items() if value is not None})
    return settings


def check_flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


#: The largest mesh (nodes) an environment accepts unless told otherwise (``max_nodes``): a reset
#: solves the start equilibrium under gravity (and TumorPositioning its goal) by Newton steps on the
#: 3 N-dof tangent, whose sparse factorisations cost about dofs^2, so past this size a reset takes
#: tens of seconds (benchmarks/large_mesh.py measures it per shape: the performance page's "Work
#: against mesh size"). The task defaults have at most 726 nodes.
MAX_NODES = 4_000
#: Past this many nodes (with ``max_nodes`` raised or None) the env warns that a reset takes long.
SLOW_NODES = 2_500


def check_work(shape, max_nodes, nodes=None):
    """Refuse (ValueError) a mesh ``shape`` (elements per axis) with more nodes than ``max_nodes``
    (None: no limit), naming the limit and the alternatives; warn past SLOW_NODES nodes, saying why
    a reset will take long. ``nodes``: the mesh's node count (None: a full block's, (nx + 1)
    (ny + 1) (nz + 1); a mesh from a mask over a grid of ``shape`` voxels has fewer)."""
    nodes = int(np.prod(np.asarray(shape) + 1)) if nodes is None else int(nodes)
    if max_nodes is not None:
        max_nodes = positive_scalar("max_nodes", max_nodes, "nodes")
        if nodes > max_nodes:
            raise ValueError(
                f"shape {tuple(shape)} has {nodes} nodes, more than max_nodes={max_nodes:g}: every reset would "
                f"solve a {3 * nodes}-dof static equilibrium (sparse factorisations whose cost grows as about "
                "dofs^2: minutes per reset on a laptop) and every step a system as large. Use a coarser shape "
                "(sim_core.resolution.choose_resolution finds the coarsest that meets an accuracy), or pass "
                "max_nodes=None to accept the cost; for a single large static scene use sim_core.solve_static, "
                "whose linear_solver='iterative' (AMG) keeps memory linear in the mesh size")
    if nodes > SLOW_NODES:
        warnings.warn(
            f"shape {tuple(shape)} has {nodes} nodes (more than {SLOW_NODES}): a reset solves a {3 * nodes}-dof "
            "static equilibrium by Newton with sparse factorisations and may take from tens of seconds to "
            "minutes; steps take tens to hundreds of ms", UserWarning, stacklevel=3)
    return nodes


def check_shape(name, value, minimum):
    try:
        shape = tuple(int(s) for s in value)
        exact = all(float(s) == v for s, v in zip(value, shape))
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be three integers (nx, ny, nz), got {value!r}") from error
    if len(shape) != 3 or not exact or any(s < m for s, m in zip(shape, minimum)):
        raise ValueError(f"{name} must be three integers (nx, ny, nz) >= {tuple(minimum)}, got {value!r}")
    return shape


def check_model(model, hourglass_control, volume_stiffness):
    """(model, hourglass_control, volume_stiffness) of a task's keywords, with the model's defaults
    (``MODEL_DEFAULTS``) for None; ValueError for an unknown model or a keyword that does not apply
    to it ("baudet-hyperelastic" takes no hourglass control and no volume forces: build_model
    refuses them). For "baudet-hyperelastic" both are returned as 0."""
    if not isinstance(model, str) or model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}, got {model!r}")
    if model == "baudet-hyperelastic":
        if hourglass_control is not None and nonnegative_scalar("hourglass_control", hourglass_control) != 0:
            raise ValueError(f"hourglass_control does not apply to model='baudet-hyperelastic' (its springs resist the "
                             f"hourglass modes, and hourglass control is not objective); leave it unset or 0, got "
                             f"{hourglass_control!r}")
        if volume_stiffness is not None:
            raise ValueError(f"volume_stiffness does not apply to model='baudet-hyperelastic' (its neo-Hookean stress "
                             f"correction holds the volume, no volume forces); leave it unset, got {volume_stiffness!r}")
        return model, 0.0, 0.0
    default_alpha, default_kappa = MODEL_DEFAULTS[model]
    alpha = nonnegative_scalar("hourglass_control", default_alpha if hourglass_control is None else hourglass_control)
    kappa = nonnegative_scalar("volume_stiffness", default_kappa if volume_stiffness is None else volume_stiffness)
    return model, alpha, kappa
