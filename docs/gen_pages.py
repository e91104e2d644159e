"""Write the generated pages of the documentation site from the code and the benchmark results.

Usage (from the repository root): python docs/gen_pages.py [--check]

Writes
  docs/tasks/<task>.md           one page per task, from the task class docstring and tissue_env.ENV_IDS
  docs/generated/validation.md   from benchmarks/results/validation_summary.json and validation_*.csv
  docs/generated/environment_accuracy.md
                                 from env_accuracy.json, env_models*.json, dynamic_convergence*.json,
                                 env_speed.json, vector_env_speed.json, material_range.json and the
                                 task classes' defaults (the page's prose is here, its numbers are not)
  docs/generated/performance.md  from step_speed.json, env_speed*.json, reset_speed.json, snapshots.json,
                                 vector_env_speed*.json, visual_speed.json, stability*.csv,
                                 speed_accuracy.json, peers.json
  docs/generated/training.md     from training.json, training_batched.json, training_pixels.json,
                                 training_speed.json, rllib_throughput*.json
  README.md                      its task table (from the task classes and tissue_env.ENV_IDS) and its
                                 training table (from training.json), between their markers

Every number on these pages is read from a results file; every table is captioned with the command
that regenerates its file (taken from the Makefile, or from the file's own metadata). The output is
deterministic, so tests/test_docs.py can check that the committed pages are up to date. ``--check``
writes nothing and exits 1 if a page differs from what would be written.

The pages are built by the modules of docs/pagegen/ (one per page, their shared helpers in
``pagegen.common``); this script runs them, and re-exports the helpers (``num``, ``pct``, ``table``,
``shape_label``, ``triple``, ...) for the tests and scripts that load it.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
for _path in (ROOT, ROOT / "docs"):  # the worktree's packages, not an installed copy; and docs/pagegen
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

from pagegen.accuracy import environment_accuracy_page  # noqa: E402
from pagegen.common import (DOCS, HEADER, QUANTITIES, RESULTS, TASK_PAGES, caption, command_for,  # noqa: E402
                            figure, load, load_csv, num, pct, runnable, shape_label, short_id, stability, table,
                            task_classes, triple)
from pagegen.performance import performance_page  # noqa: E402
from pagegen.readme import readme  # noqa: E402
from pagegen.tasks import task_page  # noqa: E402
from pagegen.training import training_page  # noqa: E402
from pagegen.validation import validation_page  # noqa: E402

__all__ = ["pages", "main", "task_page", "validation_page", "environment_accuracy_page", "performance_page",
           "training_page", "readme", "DOCS", "HEADER", "QUANTITIES", "RESULTS", "ROOT", "TASK_PAGES", "caption",
           "command_for", "figure", "load", "load_csv", "num", "pct", "runnable", "shape_label", "short_id",
           "stability", "table", "task_classes", "triple"]


def pages():
    """{path relative to the repository root: text} of every generated page (and of README.md,
    whose tables are generated)."""
    result = {f"docs/tasks/{page}.md": task_page(env_id) for env_id, page in TASK_PAGES.items()}
    result["docs/generated/validation.md"] = validation_page()
    result["docs/generated/environment_accuracy.md"] = environment_accuracy_page()
    result["docs/generated/performance.md"] = performance_page()
    result["docs/generated/training.md"] = training_page()
    result["README.md"] = readme()
    return result


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    check = "--check" in argv
    stale = []
    for relative, text in pages().items():
        path = ROOT / relative
        if check:
            if not path.exists() or path.read_text() != text:
                stale.append(relative)
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
    if stale:
        print("out of date (run python docs/gen_pages.py):", ", ".join(stale))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
