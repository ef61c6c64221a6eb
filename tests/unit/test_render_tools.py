"""The fly-by demo and the throughput benchmark (structure only; no timing asserts)."""

import cv2
import numpy as np
import pytest

from uav_landing_vision.render import benchmark, context, flyby


def test_flyby_writes_frames_with_the_uav(tmp_path):
    paths = flyby.render_flyby(tmp_path / "frames", frames=3)
    assert [p.name for p in paths] == ["flyby_000.png", "flyby_001.png", "flyby_002.png"]
    background = flyby.sky_and_sea(1280, 720)[..., ::-1]
    changed = []
    for path in paths:
        image = cv2.imread(str(path))
        assert image.shape == (720, 1280, 3)
        changed.append(int(np.any(image != background, axis=2).sum()))
    assert 0 < changed[0] < changed[-1]  # visible from the first frame, growing as it approaches


def test_flyby_approaches_the_camera():
    quats, trans = flyby.flyby_poses(10)
    assert trans[0, 2] > 50 and trans[-1, 2] < 10 and np.all(np.diff(trans[:, 2]) < 0)
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0)


def test_benchmark_rows():
    rows = benchmark.run(particles=(3, 5), tiles=(16,), repeats=2)
    assert [(r["mesh"], r["particles"], r["tile"]) for r in rows] == [("low", 3, 16), ("low", 5, 16), ("high", 5, 16)]
    assert all(r["ms"] > 0 and r["particles_per_s"] > 0 for r in rows)
    text = benchmark.format_rows(rows)
    assert "particles/s" in text and text.count("\n") == 4


def test_context_failure_names_the_packages(monkeypatch):
    def fail(**kwargs):
        raise Exception("libGL.so not loaded")

    monkeypatch.setattr(context, "_CONTEXT", None)
    monkeypatch.setattr(context.moderngl, "create_standalone_context", fail)
    with pytest.raises(RuntimeError, match="libegl1 libgl1"):
        context.gl_context()
