"""Detector timing for ``make bench``: ms per 1280×720 frame with the shipped ONNX models."""

import time

import numpy as np


def run(repeats: int = 20, threads: int = 2, width: int = 1280, height: int = 720) -> dict:
    """``{"median_ms", "p90_ms", "threads", "size", "verifier_median_ms", "verifier_boxes"}``:
    :meth:`.Detector.detect` on a full frame (a sky-and-sea backdrop, after one warm-up call),
    and the shipped box verifier on as many boxes as the detector may return (its worst case;
    the backdrop itself has no boxes to verify)."""
    from ..render.backdrop import sky_and_sea
    from .detector import Detector, DetectorConfig
    from .verifier import BoxVerifier

    config = DetectorConfig(threads=threads)
    detector = Detector(config)
    frame = sky_and_sea(width, height)
    n = config.max_detections
    x = np.linspace(50, width - 450, n)
    boxes = np.stack([x, np.full(n, height / 2), x + np.geomspace(12, 400, n), np.full(n, height / 2 + 20)], 1)
    verifier = BoxVerifier("verifier.onnx", threads)
    timed = {"detector": lambda: detector.detect(frame), "verifier": lambda: verifier.probabilities(frame, boxes)}
    medians, p90 = {}, {}
    for name, call in timed.items():
        call()
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            call()
            times.append(1e3 * (time.perf_counter() - start))
        medians[name], p90[name] = float(np.median(times)), float(np.percentile(times, 90))
    return {"median_ms": medians["detector"], "p90_ms": p90["detector"], "threads": threads, "size": (width, height),
            "verifier_median_ms": medians["verifier"], "verifier_boxes": n}


def format_result(result: dict) -> str:
    w, h = result["size"]
    text = (f"Detector (onnxruntime, {result['threads']} threads), {w}x{h} frame: "
            f"median {result['median_ms']:.1f} ms, p90 {result['p90_ms']:.1f} ms")
    return text + f"; box verifier (when on) on {result['verifier_boxes']} boxes: median {result['verifier_median_ms']:.1f} ms"
