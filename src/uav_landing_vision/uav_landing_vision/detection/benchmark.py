"""Detector timing for ``make bench``: ms per 1280×720 frame with the shipped ONNX models."""

import time

import numpy as np


def run(repeats: int = 20, threads: int = 2, width: int = 1280, height: int = 720) -> dict:
    """``{"median_ms", "p90_ms", "threads", "size", "verifier_median_ms", "verifier_boxes"}``:
    :meth:`.Detector.detect` on a full frame (a sky-and-sea backdrop, after one warm-up call),
    and the box verifier alone on as many boxes as the detector may return (its worst case;
    the backdrop itself has no boxes to verify)."""
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
    result = {"median_ms": float(np.median(times)), "p90_ms": float(np.percentile(times, 90)),
              "threads": threads, "size": (width, height), "verifier_median_ms": None, "verifier_boxes": 0}
    if detector.verifier is not None:
        n = detector.config.max_detections
        x = np.linspace(50, width - 150, n)
        boxes = np.stack([x, np.full(n, height / 2), x + np.geomspace(12, 400, n), np.full(n, height / 2 + 20)], 1)
        times = []
        for _ in range(repeats + 1):
            start = time.perf_counter()
            detector.verifier.probabilities(frame, boxes)
            times.append(1e3 * (time.perf_counter() - start))
        result.update(verifier_median_ms=float(np.median(times[1:])), verifier_boxes=n)
    return result


def format_result(result: dict) -> str:
    w, h = result["size"]
    text = (f"Detector (onnxruntime, {result['threads']} threads), {w}x{h} frame: "
            f"median {result['median_ms']:.1f} ms, p90 {result['p90_ms']:.1f} ms")
    if result["verifier_median_ms"] is not None:
        text += f"; box verifier on {result['verifier_boxes']} boxes: median {result['verifier_median_ms']:.1f} ms"
    return text
