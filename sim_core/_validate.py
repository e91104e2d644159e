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


def real_scalar(name: str, value, allowed: str) -> float:
    """``value`` as a float when it is one real number (not a bool, string or array), else a
    ``ValueError`` saying what ``name`` must be (``allowed``, e.g. "a finite number > 0")."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        if isinstance(value, np.ndarray) and value.ndim == 0 and np.issubdtype(value.dtype, np.number) \
                and not np.issubdtype(value.dtype, np.complexfloating):
            return float(value)
        kind = f"an array of shape {np.shape(value)}" if isinstance(value, (np.ndarray, list, tuple)) \
            else f"{type(value).__name__} {value!r}"
        raise ValueError(f"{name} must be {allowed}, got {kind}")
    return float(value)


def positive_scalar(name: str, value, unit: str = "") -> float:
    """A finite real number > 0 (``unit`` for the message, e.g. "m"), as a float."""
    allowed = "a finite number > 0" + (f" ({unit})" if unit else "")
    number = real_scalar(name, value, allowed)
    if not np.isfinite(number) or number <= 0:
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return number


def integer_at_least(name: str, value, minimum: int) -> int:
    """An integer >= ``minimum`` (an integral float such as 40.0 is accepted), as an int."""
    allowed = f"an integer >= {minimum}"
    number = real_scalar(name, value, allowed)
    if not np.isfinite(number) or not number.is_integer() or number < minimum:
        raise ValueError(f"{name} must be {allowed}, got {value!r}")
    return int(number)


def count_not_finite(array) -> int:
    """How many entries of ``array`` are NaN or infinite."""
    return int(np.size(array) - np.count_nonzero(np.isfinite(array)))
