"""A first run that says what it does: one message when numba starts compiling the kernels of
``sim_core.kernels`` (they were not in its cache), then a progress line every ``PROGRESS_SECONDS``
while it goes on.

After an install, the first environment step compiles the kernels it calls; they are cached
(``cache=True``), so later processes load them in seconds. ``tissue-gym-warmup`` compiles every
kernel the environments call ahead of time. The lines go through :mod:`logging`, logger
``sim_core.kernels`` at level WARNING, so that a program with no logging set up shows them on
stderr (Python's last-resort handler) and never on stdout. Silence them with::

    import logging
    logging.getLogger("sim_core.kernels").setLevel(logging.ERROR)

How it knows: numba's event API (``numba.core.event``) announces a ``"numba:compile"`` event only
when a dispatcher compiles a signature that its cache did not have; loading from the cache raises
none. The listener is installed when ``sim_core`` is imported (``install``), so the kernels'
modules themselves are untouched.
"""

from __future__ import annotations

import logging
import threading
import time

from numba.core import event as _event

#: the logger of the messages (a child of "sim_core")
LOGGER = logging.getLogger("sim_core.kernels")
#: the modules whose compilations are reported
PREFIX = "sim_core.kernels"
#: seconds between two progress lines while the kernels compile
PROGRESS_SECONDS = 30.0
#: the first line: what is happening, for how long, and how to do it ahead of time
MESSAGE = ("tissue-gym: compiling numba kernels, not in numba's cache yet (first run after an install or upgrade): "
           "about 1.5 min of CPU for the first task, 0.5 min for each further one, once; later runs load them in "
           "seconds. `tissue-gym-warmup` compiles them all ahead of time. "
           "Silence: logging.getLogger(\"sim_core.kernels\").setLevel(logging.ERROR)")
#: measured with a fresh NUMBA_CACHE_DIR (CHANGELOG, Unreleased): TumorPositioning's first reset and
#: step run 95 numba compilations (its kernels and the numba functions they call) in 86 s of CPU,
#: Palpation's after it 31 more in 31 s


class CompileNotice(_event.Listener):
    """A numba event listener (``numba.core.event.Listener``) that reports the
    compilations of ``PREFIX``'s kernels: ``MESSAGE`` at the first, then ``compiled N kernels in
    T s`` every ``PROGRESS_SECONDS``. ``compiled`` counts the compilations seen."""

    def __init__(self):
        self._lock = threading.Lock()
        self.compiled = 0
        self.started = None
        self._last = None

    @staticmethod
    def _ours(event) -> bool:
        function = getattr(event.data.get("dispatcher"), "py_func", None)
        return getattr(function, "__module__", "").startswith(PREFIX)

    def on_start(self, event):
        if not self._ours(event):
            return
        with self._lock:
            if self.started is None:
                self.started = self._last = time.perf_counter()
                LOGGER.warning(MESSAGE)

    def on_end(self, event):
        if not self._ours(event):
            return
        with self._lock:
            now = time.perf_counter()
            self.compiled += 1
            if now - self._last >= PROGRESS_SECONDS:
                self._last = now
                LOGGER.warning("tissue-gym: compiled %d kernels in %.0f s, still compiling...", self.compiled,
                               now - self.started)


_notice = None


def install() -> CompileNotice:
    """Register the listener with numba once per process (idempotent); returns it."""
    global _notice
    if _notice is None:
        _notice = CompileNotice()
        _event.register("numba:compile", _notice)
    return _notice
