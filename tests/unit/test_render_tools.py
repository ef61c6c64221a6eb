"""The throughput benchmark (structure only; no timing asserts)."""

import pytest

from uav_landing_vision.render import benchmark, context


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
    with pytest.raises(context.GLContextError, match="libegl1 libgl1"):
        context.gl_context()
