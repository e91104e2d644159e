"""Linear-elastic isotropic material parameters and the tissue's damping law (SI units)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import finite_array, positive, positive_scalar, real_scalar

#: Baudet's edge stiffness of a cube, ``E l (4 nu + 1) / (8 (1 + nu))`` (docs/physics.md section 2),
#: is not positive for nu <= -1/4, so the mass-spring model cannot represent such materials.
MIN_POISSON_RATIO = -0.25
MAX_POISSON_RATIO = 0.5


@dataclass(frozen=True)
class Material:
    """Isotropic linear-elastic material.

    Args:
        young_modulus: Young's modulus E in Pa, > 0 (soft tissue: 1e3-1e5 Pa).
        poisson_ratio: Poisson's ratio nu, in (-0.25, 0.5) (the mass-spring edge stiffness is
            non-positive for nu <= -0.25; nu = 0.5 is incompressible and has no finite bulk modulus).
        density: mass density rho in kg/m^3, > 0 (water: 1000).
        damping_ratio: None (default: no damping law; ``build_model`` then gives each spring its
            dashpot of docs/physics.md section 5, whose effect depends on the mesh) or the fraction
            zeta >= 0 of critical damping that a vibration mode of frequency ``damping_frequency``
            has: Rayleigh damping C = alpha M + beta K, a property of the tissue (section 14).
        damping_frequency: Hz, > 0. One frequency f: stiffness-proportional damping (alpha = 0,
            beta = zeta / (pi f)), so a mode of frequency f' has zeta f' / f. Two (f1 < f2):
            alpha and beta such that the modes at f1 and f2 both have zeta (and modes between them
            less). Default 1 Hz.

    E, nu and rho may each be a scalar or an array with one value per element of a mesh, which gives
    heterogeneous tissue (for example a stiffer tumour inside softer parenchyma); the damping law is
    one for the whole tissue (scalars).
    """

    young_modulus: float | np.ndarray = 1.0e4
    poisson_ratio: float | np.ndarray = 0.3
    density: float | np.ndarray = 1000.0
    damping_ratio: float | None = None
    damping_frequency: float | tuple = 1.0

    def __post_init__(self):
        young_modulus = positive("young_modulus", self.young_modulus, "Pa")
        poisson_ratio = finite_array("poisson_ratio", self.poisson_ratio)
        if np.any(poisson_ratio <= MIN_POISSON_RATIO) or np.any(poisson_ratio >= MAX_POISSON_RATIO):
            raise ValueError(
                f"poisson_ratio must lie in ({MIN_POISSON_RATIO}, {MAX_POISSON_RATIO}) for the "
                f"mass-spring model, got {self.poisson_ratio!r}"
            )
        density = positive("density", self.density, "kg/m^3")
        object.__setattr__(self, "young_modulus", _scalar_or_array(young_modulus))
        object.__setattr__(self, "poisson_ratio", _scalar_or_array(poisson_ratio))
        object.__setattr__(self, "density", _scalar_or_array(density))
        object.__setattr__(self, "damping_frequency", _frequencies(self.damping_frequency))
        if self.damping_ratio is not None:
            ratio = real_scalar("damping_ratio", self.damping_ratio, "None or a finite number >= 0")
            if not np.isfinite(ratio) or ratio < 0:
                raise ValueError(f"damping_ratio must be None or a finite number >= 0, got {self.damping_ratio!r}")
            object.__setattr__(self, "damping_ratio", ratio)

    @property
    def rayleigh(self) -> tuple[float, float]:
        """The damping law's (alpha in 1/s, beta in s): damping forces -(alpha M + beta K) v
        (docs/physics.md section 14); (0, 0) without a law (``damping_ratio`` None)."""
        if self.damping_ratio is None:
            return (0.0, 0.0)
        return rayleigh_coefficients(self.damping_ratio, self.damping_frequency)

    def modal_damping_ratio(self, frequency):
        """The damping ratio the law gives a vibration mode of ``frequency`` Hz (scalar or array):
        alpha / (2 omega) + beta omega / 2, omega = 2 pi f."""
        alpha, beta = self.rayleigh
        omega = 2.0 * np.pi * np.asarray(frequency, dtype=float)
        return alpha / (2.0 * omega) + beta * omega / 2.0

    @property
    def shear_modulus(self):
        """G = E / (2 (1 + nu)) in Pa."""
        return self.young_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def lame_lambda(self):
        """First Lame parameter lambda = E nu / ((1 + nu)(1 - 2 nu)) in Pa."""
        nu = self.poisson_ratio
        return self.young_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def bulk_modulus(self):
        """K = E / (3 (1 - 2 nu)) in Pa."""
        return self.young_modulus / (3.0 * (1.0 - 2.0 * self.poisson_ratio))

    @classmethod
    def from_labels(cls, labels, materials: dict) -> "Material":
        """Per-element material of a labelled mesh: element e gets ``materials[labels[e]]``.

        Args:
            labels: (M,) integer label id per element (``HexMesh.element_labels``).
            materials: {label id: ``Material``} with scalar parameters, one entry per label used.
        Raises:
            ValueError: labels not a 1D integer array, a label without a material, an entry that
                is not a ``Material`` with scalar parameters, or entries with different damping laws
                (the law is the whole tissue's).
        """
        labels = np.asarray(labels)
        if labels.ndim != 1 or len(labels) == 0 or not np.issubdtype(labels.dtype, np.integer):
            raise ValueError(f"labels must be a non-empty (M,) integer array, got {labels.dtype} of shape {labels.shape}")
        used = np.unique(labels)
        missing = [int(v) for v in used if int(v) not in materials]
        if missing:
            raise ValueError(f"labels {missing} have no material; materials has labels {sorted(materials)}")
        names = ("young_modulus", "poisson_ratio", "density")
        table = {}
        for label in used.tolist():
            material = materials[label]
            if not isinstance(material, cls) or any(np.ndim(getattr(material, n)) for n in names):
                raise ValueError(f"materials[{label}] must be a Material with scalar parameters, got {material!r}")
            table[label] = [getattr(material, n) for n in names]
        laws = {(materials[label].damping_ratio, materials[label].damping_frequency) for label in used.tolist()}
        if len(laws) > 1:
            raise ValueError(f"the materials' damping laws (damping_ratio, damping_frequency) differ: {sorted(laws, key=str)}; "
                             "the damping law is one for the whole tissue")
        index = np.searchsorted(used, labels)
        values = np.array([table[label] for label in used.tolist()])[index]  # (M, 3)
        return cls(*values.T, *laws.pop())

    def per_element(self, n_elements: int) -> dict[str, np.ndarray]:
        """Arrays of length ``n_elements`` for E (Pa), nu and rho (kg/m^3).

        Raises ``ValueError`` when a per-element array has the wrong length.
        """
        out = {}
        for name in ("young_modulus", "poisson_ratio", "density"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.ndim == 0:
                value = np.full(n_elements, float(value))
            elif value.shape != (n_elements,):
                raise ValueError(
                    f"{name} must be a scalar or have one value per element "
                    f"({n_elements}), got shape {value.shape}"
                )
            out[name] = value
        return out


def rayleigh_coefficients(damping_ratio: float, frequency) -> tuple[float, float]:
    """(alpha in 1/s, beta in s) of Rayleigh damping C = alpha M + beta K that gives the modes at
    ``frequency`` Hz (one: beta only; two (f1, f2): both, exact at f1 and f2) the ratio
    ``damping_ratio`` of critical damping (docs/physics.md section 14)."""
    frequencies = _frequencies(frequency)
    if isinstance(frequencies, float):
        return (0.0, damping_ratio / (np.pi * frequencies))
    w1, w2 = 2.0 * np.pi * np.asarray(frequencies)
    # zeta(w) = alpha / (2 w) + beta w / 2 equal to zeta at w1 and w2
    return (2.0 * damping_ratio * w1 * w2 / (w1 + w2), 2.0 * damping_ratio / (w1 + w2))


def _frequencies(value):
    """``damping_frequency`` checked: a float > 0 Hz or a pair (f1, f2) with 0 < f1 < f2."""
    if np.ndim(value) == 0:
        return positive_scalar("damping_frequency", value, "Hz")
    pair = np.asarray(value)
    if pair.shape != (2,) or not np.issubdtype(pair.dtype, np.number):
        raise ValueError(f"damping_frequency must be a number > 0 (Hz) or a pair (f1, f2) with 0 < f1 < f2, "
                         f"got {value!r}")
    low, high = (positive_scalar("damping_frequency", float(f), "Hz") for f in pair)
    if not low < high:
        raise ValueError(f"damping_frequency (f1, f2) must have f1 < f2, got {value!r}")
    return (low, high)


def _scalar_or_array(array: np.ndarray):
    return float(array) if array.ndim == 0 else array.copy()
