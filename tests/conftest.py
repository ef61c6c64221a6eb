"""Shared pytest fixtures."""

import os

import pytest


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """A DDS domain of this test run's own, so that parallel runs on one machine don't cross."""
    return 1 + os.getpid() % 100
