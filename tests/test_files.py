"""sim_core.files: results and figures are written whole or not at all."""

import stat

import pytest

from sim_core.files import atomic_path, atomic_write, save_figure


def test_atomic_write_replaces_whole_and_readable(tmp_path):
    path = tmp_path / "sub" / "table.csv"
    atomic_write(path, "a,b\n1,2\n")
    atomic_write(path, b"a,b\n3,4\n")
    assert path.read_text() == "a,b\n3,4\n"
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    assert [p.name for p in path.parent.iterdir()] == ["table.csv"]


def test_an_interrupted_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "result.json"
    path.write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(path) as temporary:
            temporary.write_text("half")
            raise KeyboardInterrupt
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_save_figure_keeps_the_format_of_the_suffix(tmp_path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure = plt.figure(figsize=(1, 1))
    save_figure(figure, tmp_path / "f.png", dpi=20)
    save_figure(figure, tmp_path / "f.svg")
    plt.close(figure)
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"
    assert b"<svg" in (tmp_path / "f.svg").read_bytes()[:400]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "f.svg"]
