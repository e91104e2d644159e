"""Linear-elastic isotropic material parameters (SI units)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import finite_array, positive

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

    Each argument may be a scalar or an array with one value per element of a mesh, which gives
    heterogeneous tissue (for example a stiffer tumour inside softer parenchyma).
    """

    young_modulus: float | np.ndarray = 1.0e4
    poisson_ratio: float | np.ndarray = 0.3
    density: float | np.ndarray = 1000.0

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
            ValueError: labels not a 1D integer array, a label without a material, or an entry that
                is not a ``Material`` with scalar parameters.
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
        index = np.searchsorted(used, labels)
        values = np.array([table[label] for label in used.tolist()])[index]  # (M, 3)
        return cls(*values.T)

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


def _scalar_or_array(array: np.ndarray):
    return float(array) if array.ndim == 0 else array.copy()
