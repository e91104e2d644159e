"""The documentation site: generated pages up to date, and a strict build that succeeds.

The generated pages (docs/tasks/, docs/generated/) are committed; the generator must reproduce them
byte for byte, so a changed docstring or results file cannot leave the site out of date unnoticed.
The strict build (broken links, missing anchors, unresolvable API references all fail it) runs only
where mkdocs is installed (``pip install ".[docs]"``).
"""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _generator():
    spec = importlib.util.spec_from_file_location("gen_pages", ROOT / "docs" / "gen_pages.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_generated_pages_match_the_committed_ones():
    pages = _generator().pages()
    assert {"docs/tasks/tumor-positioning.md", "docs/tasks/palpation.md", "docs/tasks/retraction.md",
            "docs/tasks/liver-needle-alignment.md", "docs/tasks/bimanual-exposure.md",
            "docs/generated/validation.md", "docs/generated/performance.md", "docs/generated/training.md",
            "docs/generated/environment_accuracy.md", "README.md"} <= set(pages)
    stale = [name for name, text in pages.items()
             if not (ROOT / name).exists() or (ROOT / name).read_text() != text]
    assert not stale, f"run `python docs/gen_pages.py` and commit: {stale}"


def test_task_pages_come_from_the_docstrings_and_the_registry():
    import inspect

    import tissue_env

    pages = _generator().pages()
    for cls, page in ((tissue_env.TumorPositioningEnv, "tumor-positioning"), (tissue_env.PalpationEnv, "palpation"),
                      (tissue_env.RetractionEnv, "retraction"),
                      (tissue_env.LiverNeedleAlignmentEnv, "liver-needle-alignment"), (tissue_env.IncisionEnv, "incision"),
                      (tissue_env.BimanualExposureEnv, "bimanual-exposure"),
                      (tissue_env.DissectionEnv, "dissection")):
        text = pages[f"docs/tasks/{page}.md"]
        first_line = inspect.getdoc(cls).splitlines()[2]  # under "## Description"
        assert first_line.replace("``", "`") in text
        env_id = next(i for i, (entry, _) in tissue_env.ENV_IDS.items() if entry.endswith(":" + cls.__name__))
        assert f"`{env_id}`" in text and f"{tissue_env.ENV_IDS[env_id][1]} env steps" in text


def test_environment_accuracy_page_reads_the_results_files():
    """The page's defaults and errors are env_accuracy.json's and env_models.json's, and each table names
    the command that regenerates its file."""
    import json

    generator = _generator()
    text = generator.pages()["docs/generated/environment_accuracy.md"]
    accuracy = json.loads((ROOT / "benchmarks" / "results" / "env_accuracy.json").read_text())
    for task, entry in accuracy["tasks"].items():
        default = entry["env_default"]
        assert f"| {task} | `{default.get('model', 'baudet')}` | {generator.shape_label(default['shape'])} |" in text
        assert generator.triple(default["discretisation"]["errors"]) in text
        assert generator.triple(default["constitutive"]["errors"]) in text
    models = json.loads((ROOT / "benchmarks" / "results" / "env_models.json").read_text())
    palpation = models["tasks"]["Palpation"]["models"]["baudet-hyperelastic"]
    assert generator.num(palpation["lowest_eigenvalue"]) in text
    for source in ("env_accuracy.json", "env_models.json", "env_models_reference_x1.5.json", "dynamic_convergence.json",
                   "dynamic_convergence_static.json", "env_speed.json", "vector_env_speed.json", "material_range.json"):
        assert f"*Regenerate `benchmarks/results/{source}`:* `python -m benchmarks." in text, source


def test_readme_tables_come_from_the_task_classes_and_the_training_results():
    import json

    import tissue_env

    readme = _generator().pages()["README.md"]
    tasks = readme.split("<!-- generated: tasks", 1)[1].split("<!-- end generated: tasks -->")[0]
    for env_id, (entry_point, max_steps) in tissue_env.ENV_IDS.items():
        cls = getattr(tissue_env, entry_point.split(":")[1])
        row = next(line for line in tasks.splitlines() if line.startswith(f"| `{env_id}`"))
        assert f"{max_steps} steps" in row
        assert all(f"`{kind}`" in row for kind in cls.observation_types())
        assert ("`goal`" in row) == (cls.goal_features is not None)
        assert all(f"`{keyword}`" in row for keyword in (*cls.randomised_parameters.values(), *cls.episode_keywords))
    training = readme.split("<!-- generated: training", 1)[1].split("<!-- end generated: training -->")[0]
    results = json.loads((ROOT / "benchmarks" / "results" / "training.json").read_text())
    assert len([line for line in training.splitlines() if line.startswith("| ") and "random / scripted" not in line]) \
        == len(results) + 1  # a row per entry, and the header
    assert "{" not in tasks  # every {keyword} of a summary was replaced by its default


def test_strict_build(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    site = tmp_path / "site"
    notes = ROOT / "docs" / "performance_notes.md"
    made_notes = not notes.exists()
    if made_notes:  # the performance page includes it; stand in for it when it is not there yet
        notes.write_text("Performance notes are not written yet.\n")
    try:
        result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                                cwd=ROOT, capture_output=True, text=True, timeout=300,
                                env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1"})
    finally:
        if made_notes:
            notes.unlink()
    assert result.returncode == 0, result.stdout + result.stderr
    warnings = [line for line in result.stderr.splitlines() if line.startswith("WARNING")]
    assert not warnings, "\n".join(warnings)
    for page in ("index.html", "physics/index.html", "api/index.html", "getting-started/index.html",
                 "tasks/tumor-positioning/index.html", "tasks/palpation/index.html", "tasks/retraction/index.html",
                 "generated/validation/index.html", "generated/performance/index.html",
                 "generated/training/index.html", "generated/environment_accuracy/index.html", "changelog/index.html"):
        assert (site / page).is_file(), page
    assert "Changelog" in (site / "changelog" / "index.html").read_text()
