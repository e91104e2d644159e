"""tissue-sim: JSON on stdout, one-line errors with exit code 2, --save writes a mesh."""

import json
import subprocess
import sys

import meshio
import pytest

from sim_core.geometry.mesh import HexMesh
from sim_core.studies.cli import main


def run_cli(*args):
    process = subprocess.run([sys.executable, "-m", "sim_core.studies.cli", *args], capture_output=True, text=True)
    return process.returncode, process.stdout, process.stderr


def test_elongation_json(capsys):
    assert main(["elongation", "--shape", "4", "4", "4", "--strain", "0.01", "--poisson-ratio", "0.4", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["converged"] is True and result["residual"] < 1e-8
    assert result["young_modulus"] == pytest.approx(1e4, rel=0.01)
    assert result["poisson_ratio"] == pytest.approx(0.4, abs=0.01)


def test_shear_compare_and_save(tmp_path, capsys):
    path = tmp_path / "sheared.vtu"
    assert main(["shear", "--shape", "4", "4", "4", "--angle-deg", "3", "--compare", "fem-linear",
                 "--save", str(path), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["compare"]["e_dm_percent"] < 2.0
    assert result["shear_modulus"] > 0
    mesh = meshio.read(path)
    assert mesh.points.shape == (125, 3) and "displacement" in mesh.point_data


def test_flexion_json(capsys):
    assert main(["flexion", "--shape", "6", "3", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["tip_deflection"] < 0


@pytest.mark.parametrize("args, word", [
    (["elongation", "--poisson-ratio", "0.7"], "poisson_ratio"),
    (["elongation", "--shape", "4", "3", "4"], "even ny and nz"),
    (["elongation", "--young-modulus", "-1"], "young_modulus"),
    (["shear", "--model", "magic"], "invalid choice"),
    (["elongation", "--strain", "0.01", "--force", "2"], "not allowed with"),
    (["bend"], "invalid choice"),
])
def test_bad_arguments_exit_2_with_one_line(args, word):
    code, out, err = run_cli(*args)
    assert code == 2
    assert word in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_bench_json(capsys):
    assert main(["bench", "--shape", "2", "2", "2", "--repeats", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    for key in ("explicit_step_ms", "implicit_step_ms", "cg_iterations", "static_solve_ms", "machine"):
        assert key in result
    assert result["explicit_step_ms"] > 0 and result["static_solve_converged"] is True


def test_version():
    import sim_core

    code, out, err = run_cli("--version")
    assert code == 0, err
    assert out.strip() == f"tissue-sim {sim_core.__version__}"
    assert sim_core.__version__.count(".") >= 2


@pytest.mark.parametrize("name, word", [("out.xyz", "'.xyz'"), ("out", "no extension"),
                                        ("missing/out.vtu", "does not exist")])
def test_save_is_checked_before_computing(tmp_path, monkeypatch, capsys, name, word):
    """A --save file the mesh writer would refuse fails at once (exit 2, one line naming the
    supported formats or the missing folder), not with a meshio traceback after the solve."""
    from sim_core.studies import cli

    def not_reached(**_):
        raise AssertionError("computed before checking --save")

    monkeypatch.setattr(cli.experiments, "elongation", not_reached)
    assert main(["elongation", "--shape", "4", "4", "4", "--save", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert word in err and len(err.strip().splitlines()) == 1
    if "does not exist" not in word:
        assert all(ext in err for ext in cli.SAVE_FORMATS)


def test_save_formats_keep_the_hexahedra_and_the_displacement(tmp_path):
    """Every extension --save accepts writes a file that reads back with its hexahedra and the
    displacement point data."""
    from sim_core.studies.cli import SAVE_FORMATS

    mesh = HexMesh.block((2, 2, 2), 0.1)
    for extension in SAVE_FORMATS:
        path = tmp_path / f"block{extension}"
        mesh.write(path, point_data={"displacement": mesh.nodes * 0.01})
        back = meshio.read(path)
        assert [cells.type for cells in back.cells] == ["hexahedron"], extension
        assert back.point_data["displacement"].shape == (27, 3), extension
