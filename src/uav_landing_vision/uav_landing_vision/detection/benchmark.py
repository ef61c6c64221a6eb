"""Detector timing for ``make bench``: ms per 1280×720 frame with the shipped ONNX model."""

import time

import numpy as np


def run(repeats: int = 20, threads: int = 2, width: int = 1280, height: int = 720) -> dict:
    """``{"median_ms", "p90_ms", "threads", "size"}`` of :meth:`.Detector.detect` on a full
    frame (a sky-and-sea backdrop), after one warm-up call."""
    from ..render.backdrop import sky_and_sea
    from .detector import Detector, DetectorConfig

    detector = Detector(DetectorConfig(threads=threads))
    frame = sky_and_sea(width, height)
    detector.detect(frame)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        detector.detect(frame)
        times.append(1e3 * (time.perf_counter() - start))
    return {"median_ms": float(np.median(times)), "p90_ms": float(np.percentile(times, 90)),
            "threads": threads, "size": (width, height)}


def format_result(result: dict) -> str:
    w, h = result["size"]
    return (f"Detector (onnxruntime, {result['threads']} threads), {w}x{h} frame: "
            f"median {result['median_ms']:.1f} ms, p90 {result['p90_ms']:.1f} ms")
