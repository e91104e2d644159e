"""Input checks shared by the physics layer: clear ``ValueError`` messages, never a silent NaN."""

from __future__ import annotations

import numpy as np


def finite_array(name: str, value, shape: tuple | None = None, dtype=float) -> np.ndarray:
    """Return ``value`` as a finite array, or raise ``ValueError`` naming ``name``.

    Args:
        name: parameter name used in the error message.
        value: array-like input.
        shape: expected shape; ``-1`` entries match any length.
        dtype: dtype of the returned array.
    """
    try:
        array = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be numeric, got {value!r}") from error
    if shape is not None:
        if array.ndim != len(shape) or any(
            expected not in (-1, actual) for expected, actual in zip(shape, array.shape)
        ):
            wanted = "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
            raise ValueError(f"{name} must have shape {wanted}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite (no NaN or infinity), got {value!r}")
    return array


def positive(name: str, value, unit: str) -> np.ndarray:
    """A finite, strictly positive scalar or array (e.g. Young's modulus in Pa)."""
    array = finite_array(name, value)
    if np.any(array <= 0):
        raise ValueError(f"{name} must be > 0 {unit}, got {value!r}")
    return array
