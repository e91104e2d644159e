"""benchmarks/task_gallery.py: the scripted episode's frames and the figure."""

import numpy as np

from benchmarks import task_gallery


def test_gallery_frames_and_figure(tmp_path):
    frames = task_gallery.episode_frames("TumorPositioning", seed=0)
    steps = [step for step, _, _ in frames]
    assert steps == list(range(len(frames)))
    assert all(frame.dtype == np.uint8 and frame.shape == frames[0][1].shape for _, frame, _ in frames)
    assert frames[-1][2]["is_success"]  # the scripted controller ends the episode by success
    path = tmp_path / "tasks.png"
    task_gallery.figure([("TumorPositioning", frames)], str(path))
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
