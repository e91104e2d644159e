"""Input checks of the scene, resolution and stepping studies: each returns the value converted,
or raises a ValueError naming the argument."""

from __future__ import annotations

import math

import numpy as np


def check_vector(name, value, *, positive=False):
    try:
        array = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number or three numbers, got {value!r}") from error
    if not np.all(np.isfinite(array)) or (positive and np.any(array <= 0)):
        raise ValueError(f"{name} must be three finite numbers{' > 0' if positive else ''}, got {value!r}")
    return array


def check_scalar(name, value, *, low=None, strict=True):
    try:
        value = float(value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a number, got {value!r}") from error
    if not math.isfinite(value) or (low is not None and (value <= low if strict else value < low)):
        raise ValueError(f"{name} must be a finite number {'>' if strict else '>='} {low}, got {value!r}")
    return value


def check_integer(name, value, low):
    if isinstance(value, bool):
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    try:
        number = int(value)
        exact = float(value) == number
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}") from error
    if not exact or number < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return number


def check_shape(name, value):
    """Three integers >= 1 (elements per axis) as a tuple."""
    try:
        shape = tuple(int(s) for s in value)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be three integers >= 1, got {value!r}") from error
    if len(shape) != 3 or min(shape) < 1:
        raise ValueError(f"{name} must be three integers >= 1, got {value!r}")
    return shape
