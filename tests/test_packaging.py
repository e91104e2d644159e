"""The package a user installs: the wheel holds the library (sim_core, tissue_env) and nothing
else, the version is the same everywhere, and ``import tissue_env`` needs no stable-baselines3."""

import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _pyproject_version() -> str:
    return re.search(r'^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.M).group(1)


def test_wheel_installs_only_the_library(tmp_path):
    """A wheel built from the clone has the top-level entries sim_core/, tissue_env/ and its
    dist-info only (no training/, tests/ or benchmarks/ that would shadow a user's folders), the
    licence and the tissue-sim script."""
    pytest.importorskip("setuptools", reason="building the wheel without isolation needs setuptools in this venv")
    # built from a copy of the clone: setuptools leaves build/ and *.egg-info next to the sources,
    # and a stale build/lib would end up in the wheel
    source = tmp_path / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(
        ".git", ".venv*", "build", "*.egg-info", "runs", "site", "__pycache__", ".pytest_cache"))
    out = tmp_path / "wheel"
    process = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation",
                              "--quiet", "-w", str(out)], capture_output=True, text=True, timeout=120)
    if process.returncode != 0 and "No module named pip" in process.stderr:
        pytest.skip("pip is not installed in this venv")
    assert process.returncode == 0, process.stderr
    (wheel,) = out.glob("tissue_gym-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    dist_info = f"tissue_gym-{_pyproject_version()}.dist-info"
    assert {name.split("/")[0] for name in names} == {"sim_core", "tissue_env", dist_info}
    assert "tissue_env/sb3.py" in names and "sim_core/kernels/forces.py" in names
    assert not [name for name in names if name.endswith((".nbi", ".nbc", ".pyc"))]
    assert f"{dist_info}/licenses/LICENSE" in names
    entry_points = zipfile.ZipFile(wheel).read(f"{dist_info}/entry_points.txt").decode()
    assert "tissue-sim = sim_core.studies.cli:main" in entry_points
    metadata = zipfile.ZipFile(wheel).read(f"{dist_info}/METADATA").decode()
    assert not re.search(r"^Requires-Dist: torch==", metadata, re.M)  # extras take lower bounds


def test_one_version_everywhere():
    """pyproject.toml, the clone's fallback, CITATION.cff and (when installed) the metadata agree."""
    from importlib import metadata

    import sim_core
    from sim_core import _SOURCE_VERSION

    version = _pyproject_version()
    assert _SOURCE_VERSION == version
    try:
        assert sim_core.__version__ == metadata.version("tissue-gym")
    except metadata.PackageNotFoundError:
        assert sim_core.__version__ == version
    assert re.search(rf'^version: "?{re.escape(version)}"?$', (ROOT / "CITATION.cff").read_text(), re.M)


def test_citation_file_is_cff_1_2():
    yaml = pytest.importorskip("yaml")
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert citation["cff-version"] == "1.2.0"
    for key in ("message", "title", "authors", "version", "license", "abstract"):
        assert citation.get(key), key
    assert citation["license"] == "MIT" and citation["title"] == "tissue-gym"
    assert all("name" in author or "family-names" in author for author in citation["authors"])


def test_import_tissue_env_does_not_import_stable_baselines3():
    """tissue_env.sb3 is imported on demand: a user without the train extra can use the envs."""
    code = ("import sys, gymnasium as gym, tissue_env\n"
            "gym.make('tissue_env/Retraction-v0')\n"
            "assert 'stable_baselines3' not in sys.modules and 'tissue_env.sb3' not in sys.modules\n"
            "assert 'training' not in sys.modules\n")
    process = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert process.returncode == 0, process.stderr


def test_training_vec_env_re_exports_the_library_class():
    pytest.importorskip("stable_baselines3")
    from tissue_env.sb3 import BatchedVecEnv, monitored
    from training import vec_env

    assert vec_env.BatchedVecEnv is BatchedVecEnv and vec_env.monitored is monitored
