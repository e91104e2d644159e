"""Where the mass-spring models are validated, and the check that says when a state leaves it.

The divergence monitor (``sim_core.solvers.solver.DivergenceMonitors``) says when a simulation is broken
(non-finite, exploding, inverted). A state can be healthy and still outside the range in which the
model's accuracy was measured: the springs' elongation and the elements' volume ratio were checked
against neo-Hookean FEM only up to moderate strains (docs/physics.md, validation). ``ValidityRange``
names those limits and ``out_of_range`` reports, per world, the first one a state exceeds, so an
environment can flag such steps instead of presenting them as trustworthy. SI units; strains and
ratios are dimensionless.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Largest |engineering strain| at which the mass-spring models are validated: the range that
#: benchmarks/validation.py compares with neo-Hookean FEM in both tension and compression (figures
#: 1-2) and that tests/test_validation.py exercises (1% and 5% tension, 20% compression).
VALIDATED_STRAIN = 0.2
#: Largest |shear angle| (degrees) at which the mass-spring models are validated: the angles at which
#: tests/test_validation.py and benchmarks/validation.py (figure 3) hold the 2% position-error floor
#: against FEM (2 to 10 degrees); beyond them the springs stiffen with the angle.
VALIDATED_SHEAR_DEG = 10.0


@dataclass(frozen=True)
class ValidityRange:
    """The validated range of a state.

    Attributes:
        max_strain: largest spring strain |L / L0 - 1| (``VALIDATED_STRAIN``).
        volume_ratio: (low, high) bounds of every element's volume ratio V / V0: a uniaxial
            strain of ``max_strain`` changes an element's volume by at most that fraction (Poisson
            ratio 0; less for larger ones), so (1 - max_strain, 1 + max_strain) by default.
    """

    max_strain: float = VALIDATED_STRAIN
    volume_ratio: tuple = (1.0 - VALIDATED_STRAIN, 1.0 + VALIDATED_STRAIN)

    def __post_init__(self):
        low, high = (float(value) for value in self.volume_ratio)
        if not (np.isfinite(self.max_strain) and self.max_strain > 0):
            raise ValueError(f"max_strain must be a finite strain > 0, got {self.max_strain!r}")
        if not (0 < low < 1 < high and np.isfinite(high)):
            raise ValueError(f"volume_ratio must be (low, high) with 0 < low < 1 < high, got {self.volume_ratio!r}")


def out_of_range(max_strain, volume_ratio_low, volume_ratio_high, valid: ValidityRange = ValidityRange()) -> np.ndarray:
    """(N,) object: per world, why its state is outside ``valid`` (the first limit exceeded), None
    where it is inside. ``max_strain`` (N,) the largest spring strain, ``volume_ratio_low`` and
    ``volume_ratio_high`` (N,) the smallest and largest element volume ratio V / V0."""
    strain = np.asarray(max_strain, dtype=float)
    low, high = np.asarray(volume_ratio_low, dtype=float), np.asarray(volume_ratio_high, dtype=float)
    reasons = np.full(strain.shape, None, dtype=object)
    for index in np.flatnonzero(strain > valid.max_strain):
        reasons[index] = (f"spring strain {strain[index]:.3g} beyond the validated {valid.max_strain:g} "
                          "(the model's accuracy is not measured there)")
    lower, upper = valid.volume_ratio
    for index in np.flatnonzero((low < lower) | (high > upper)):
        if reasons[index] is None:
            reasons[index] = (f"element volume ratio {low[index]:.3g}-{high[index]:.3g} outside the validated "
                              f"{lower:g}-{upper:g}")
    return reasons


#: The validated range of a model on hexahedra where it is measured beyond the default: the largest
#: spring strain and the volume ratios of a state within 2% of converged neo-Hookean FEM at the tip
#: and 2 in %e_dm, rounded inward (``python -m benchmarks.validated_range``,
#: benchmarks/results/validated_range.json: baudet-hyperelastic's hanging cantilever, its tip 1.14 m
#: down on a 1 m beam, within 0.70% and %e_dm 1.13, spring strain up to 1.560, volume ratios
#: 0.602-1.467). "baudet" misses that floor (52% short) and keeps the default; tetrahedra lock in
#: bending (issue 42) and keep it too.
MODEL_RANGES = {"baudet-hyperelastic": ValidityRange(max_strain=1.5, volume_ratio=(0.61, 1.45))}


def model_range(model: str, hexahedral: bool = True) -> ValidityRange:
    """The validated range of ``model`` (a ``build_model`` key) on hexahedra (``hexahedral``) or
    tetrahedra: its own where ``MODEL_RANGES`` has one, else the default ``ValidityRange()``."""
    return MODEL_RANGES.get(model, ValidityRange()) if hexahedral else ValidityRange()
