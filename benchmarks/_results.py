"""Shared by the benchmark scripts: writing their result files."""

from __future__ import annotations

import json
import os
import tempfile


def write_json(path, data, **dump_options) -> None:
    """Write ``data`` as JSON to ``path`` atomically (a temporary file in the same directory, then
    ``os.replace``: a crash or an interrupted run never leaves half a file), readable by all
    (mode 0644, where ``tempfile.mkstemp`` alone gives 0600). ``dump_options`` go to ``json.dump``
    (default ``indent=2``)."""
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=directory, suffix=".tmp")
    try:
        with os.fdopen(handle, "w") as stream:
            json.dump(data, stream, **{"indent": 2, **dump_options})
            stream.write("\n")
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise
