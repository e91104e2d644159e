"""Files written whole or not at all: results, tables and figures of long runs.

``atomic_path`` gives a temporary file of its own beside the destination and moves it onto the
destination (``os.replace``) only when the writing succeeded, so an interrupted run never leaves
half a file, a reader never sees one, and two writers never share a temporary. The files are
readable by all (mode 0644; ``tempfile.mkstemp`` alone gives 0600)."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path):
    """Yield a temporary ``Path`` in ``path``'s folder (created if missing) with ``path``'s
    suffix (matplotlib's ``savefig`` and PIL read the format from it); on leaving the block
    without an exception it replaces ``path``, else it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp" + path.suffix)
    os.close(handle)
    try:
        yield Path(temporary)
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise


def atomic_write(path, data) -> Path:
    """Write ``data`` (str: UTF-8 text, or bytes) to ``path`` atomically (``atomic_path``)."""
    with atomic_path(path) as temporary:
        if isinstance(data, str):
            temporary.write_text(data, encoding="utf-8")
        else:
            temporary.write_bytes(data)
    return Path(path)


def save_figure(figure, path, **options) -> Path:
    """``figure.savefig(path, **options)`` atomically (``atomic_path``)."""
    with atomic_path(path) as temporary:
        figure.savefig(temporary, **options)
    return Path(path)


def finish_figure(figure, path, *, rect=None, **options) -> Path:
    """Lay ``figure`` out (``tight_layout`` within ``rect``, the whole figure when None), write it
    to ``path`` atomically (``save_figure``, ``options`` for ``savefig``) and close it."""
    import matplotlib.pyplot as plt  # only the scripts that draw need matplotlib

    figure.tight_layout(rect=rect)
    save_figure(figure, path, **options)
    plt.close(figure)
    return Path(path)
