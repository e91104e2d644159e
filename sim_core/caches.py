"""Least-recently-used caches with a budget in bytes, so a long run's memory stays bounded.

Every cache that keeps factorisations, models or other per-state data across resets is a
``BudgetCache``: it drops its least recently used entries once the bytes its entries hold pass its
budget (and, if given, past a number of entries). The budgets are per cache kind, in bytes:

======================  ==========  ============================================================
kind                    default     what it keeps
======================  ==========  ============================================================
``"models"``            256 MiB     an env's built models (one per drawn material) and their
                                    derived data; shared by a vector env's copies
``"start_factors"``     256 MiB     the implicit step's LU factors at an episode's start, per
                                    start state, imposed set and time step (each with the inverse
                                    columns and capacitance corrections it has grown)
``"static_factors"``    128 MiB     ``solve_static``'s tangent LUs (``static.FactorCache``)
======================  ==========  ============================================================

``set_cache_budget(kind, bytes)`` changes a kind's budget for the live caches and those made later
(a run with many distinct materials, e.g. domain randomisation, never hits its model cache, so a
small budget costs nothing there); ``cache_usage()`` reports what every live cache holds.
An entry's size is measured (``nbytes``) when an entry is added, so entries that grow while in use
(a factor's inverse columns) are counted at their current size; the newest entry is always kept,
even when it alone passes the budget.
"""

from __future__ import annotations

import hashlib
import threading
import weakref
from collections import OrderedDict

import numpy as np
import scipy.sparse as sp

MIB = 1 << 20

#: default budget per cache kind, bytes (module docstring)
DEFAULT_BUDGETS = {"models": 256 * MIB, "start_factors": 256 * MIB, "static_factors": 128 * MIB}
_budgets = dict(DEFAULT_BUDGETS)
_live: "weakref.WeakSet[BudgetCache]" = weakref.WeakSet()
_registry_lock = threading.Lock()


def nbytes(value, _seen=None) -> int:
    """Bytes held by ``value``: numpy arrays (their buffers; a view its base's), scipy sparse matrices, SuperLU factors
    (L and U: 12 bytes per stored entry), containers, numba typed Lists and plain objects'
    attributes, each object counted once. A ``Model`` inside another value counts as 0 (a factor
    refers to its model; the model is counted by the model cache that holds it)."""
    return _nbytes(value, set() if _seen is None else _seen, True)


def _nbytes(value, seen, top) -> int:
    if value is None or isinstance(value, (bool, int, float, complex, str)) or id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, bytes):
        return len(value)
    if isinstance(value, np.ndarray):
        # a view keeps its base's whole buffer alive: count the base (once)
        return _nbytes(value.base, seen, False) if isinstance(value.base, np.ndarray) else value.nbytes
    if sp.issparse(value):
        return sum(_nbytes(getattr(value, name, None), seen, False) for name in ("data", "indices", "indptr", "row", "col"))
    kind = type(value).__name__
    if kind == "SuperLU":
        return 12 * int(value.nnz) + 16 * value.shape[0]
    if kind == "Model" and not top:
        return 0
    if isinstance(value, BudgetCache):
        return value.nbytes
    if isinstance(value, dict):
        return sum(_nbytes(k, seen, False) + _nbytes(v, seen, False) for k, v in value.items())
    if isinstance(value, (list, tuple, set, frozenset)) or kind == "List":
        return sum(_nbytes(item, seen, False) for item in value)
    attributes = getattr(value, "__dict__", None)
    if attributes is not None:
        return sum(_nbytes(item, seen, False) for item in attributes.values())
    return 0


def set_cache_budget(kind: str, budget_bytes: int) -> None:
    """Set the byte budget of every cache of ``kind`` (``DEFAULT_BUDGETS``' keys), live or later;
    live caches drop their oldest entries at once down to it."""
    if kind not in _budgets:
        raise ValueError(f"kind must be one of {sorted(_budgets)}, got {kind!r}")
    if isinstance(budget_bytes, bool) or not isinstance(budget_bytes, (int, np.integer)) or budget_bytes < 0:
        raise ValueError(f"budget_bytes must be an integer >= 0 (bytes), got {budget_bytes!r}")
    _budgets[kind] = int(budget_bytes)
    with _registry_lock:
        caches = [cache for cache in _live if cache.kind == kind]
    for cache in caches:
        cache.trim()


def cache_budget(kind: str) -> int:
    """The current byte budget of the caches of ``kind``."""
    if kind not in _budgets:
        raise ValueError(f"kind must be one of {sorted(_budgets)}, got {kind!r}")
    return _budgets[kind]


def cache_usage() -> dict:
    """{kind: dict(caches, entries, bytes, budget)} over the live caches (bytes as last measured)."""
    with _registry_lock:
        caches = list(_live)
    usage = {kind: dict(caches=0, entries=0, bytes=0, budget=budget) for kind, budget in _budgets.items()}
    for cache in caches:
        row = usage[cache.kind]
        row["caches"] += 1
        row["entries"] += len(cache)
        row["bytes"] += cache.nbytes
    return usage


class BudgetCache:
    """An LRU map whose entries together hold at most the budget of its ``kind`` in bytes (module
    docstring), and at most ``max_entries`` entries if given. Thread-safe. Pickles (and deep-copies)
    empty: its entries are a cache, recomputed on demand."""

    def __init__(self, kind: str, max_entries: int | None = None):
        cache_budget(kind)  # validates the kind
        self.kind = kind
        self.max_entries = None if max_entries is None else int(max_entries)
        self._entries: OrderedDict = OrderedDict()
        self._sizes: dict = {}
        self._lock = threading.RLock()
        with _registry_lock:
            _live.add(self)

    @property
    def budget(self) -> int:
        return _budgets[self.kind]

    @property
    def nbytes(self) -> int:
        """Bytes held by the entries, as measured when each was last added or re-measured."""
        return sum(self._sizes.values())

    def get(self, key, default=None):
        """The entry of ``key`` (now the most recently used), or ``default``."""
        with self._lock:
            if key not in self._entries:
                return default
            self._entries.move_to_end(key)
            return self._entries[key]

    def put(self, key, value):
        """Add (or replace) the entry of ``key``, re-measure the entries, drop the least recently
        used ones past the budget; returns ``value``."""
        with self._lock:
            self._entries[key] = value
            self._entries.move_to_end(key)
            self.trim()
        return value

    def trim(self):
        """Re-measure every entry and drop the oldest while over the budget (the newest stays)."""
        with self._lock:
            # one ``seen`` set: data shared between entries (a factor's structure) counts once
            seen: set = set()
            self._sizes = {key: nbytes(value, seen) for key, value in self._entries.items()}
            total = sum(self._sizes.values())
            while len(self._entries) > 1 and (
                    total > self.budget or (self.max_entries is not None and len(self._entries) > self.max_entries)):
                key, _ = self._entries.popitem(last=False)
                total -= self._sizes.pop(key)

    def values(self) -> list:
        with self._lock:
            return list(self._entries.values())

    def clear(self):
        with self._lock:
            self._entries.clear()
            self._sizes.clear()

    def __contains__(self, key) -> bool:
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def __getstate__(self):
        return dict(kind=self.kind, max_entries=self.max_entries)

    def __setstate__(self, state):
        self.__init__(state["kind"], state["max_entries"])


def digest(array) -> bytes:
    """A 16-byte hash of an array's bytes (cache keys: imposed sets, hourglass matrices)."""
    return hashlib.blake2b(np.ascontiguousarray(array).view(np.uint8), digest_size=16).digest()
