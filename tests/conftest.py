"""Shared pytest fixtures."""

import fcntl
import os
import tempfile
import time
from pathlib import Path

import pytest

DOMAINS = range(1, 101)  # ROS 2 domain ids 1..100; 0 is every graph's default
PROBE_S = 1.0  # long enough for DDS participants on the domain to announce themselves


def _domain_in_use(domain_id: int) -> bool:
    """Whether any other DDS participant with a ROS node shows on ``domain_id`` (a live graph, another test run)."""
    import rclpy
    from rclpy.node import Node

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        node = Node("domain_probe", context=context)
        deadline = time.monotonic() + PROBE_S
        others = []
        while time.monotonic() < deadline and not others:
            time.sleep(0.1)
            others = [name for name in node.get_node_names() if name != "domain_probe"]
        node.destroy_node()
        return bool(others)
    finally:
        context.try_shutdown()


@pytest.fixture(scope="session")
def ros_domain_id():
    """A DDS domain of this test run's own: not the shell's ``ROS_DOMAIN_ID`` (a live graph's),
    locked against other test runs on this machine, and with no ROS node on it when claimed, so
    that a test's poses never reach a running system's GCS bridge, nor another run's."""
    live = os.environ.get("ROS_DOMAIN_ID", "0")
    start = os.getpid() % len(DOMAINS)
    for k in range(len(DOMAINS)):
        domain_id = DOMAINS[(start + k) % len(DOMAINS)]
        if str(domain_id) == live:
            continue
        lock = (Path(tempfile.gettempdir()) / f"uav_landing_test_domain_{domain_id}.lock").open("w")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.close()
            continue
        if _domain_in_use(domain_id):
            lock.close()
            continue
        yield domain_id
        lock.close()
        return
    pytest.fail(f"no free ROS domain among {DOMAINS.start}..{DOMAINS.stop - 1}")


@pytest.fixture
def shift_rasterisation(monkeypatch):
    """``shift(tile_px)``: the renderer then draws every silhouette ``tile_px`` tile pixels right of
    where its box says, as an OpenGL with another pixel-centre rule would (the self-test's fault)."""
    import numpy as np

    from uav_landing_vision.render import renderer, selftest

    real = renderer.tile_boxes

    def shift(tile_px: float) -> None:
        def shifted(*args):
            boxes, visible = real(*args)
            step = tile_px * (boxes[:, 2] - boxes[:, 0]) / selftest.TILE
            return boxes - np.stack([step, 0 * step, step, 0 * step], axis=1), visible

        monkeypatch.setattr(renderer, "tile_boxes", shifted)

    return shift


@pytest.fixture
def interrupt_at_second_call(monkeypatch):
    """``interrupt(module, name, run)``: ``run()`` with ``module.name`` raising KeyboardInterrupt at
    its second call (Ctrl-C in a training run's second validation: its last.pt holds epoch 1), the
    interrupt expected; ``module.name`` is itself again afterwards."""

    def interrupt(module, name: str, run) -> None:
        original, calls = getattr(module, name), []

        def interrupted(*args, **kwargs):
            calls.append(1)
            if len(calls) == 2:
                raise KeyboardInterrupt
            return original(*args, **kwargs)

        monkeypatch.setattr(module, name, interrupted)
        with pytest.raises(KeyboardInterrupt):
            run()
        monkeypatch.setattr(module, name, original)

    return interrupt
