"""Shared pytest fixtures: real-data location, isolated ROS 2 contexts on loopback."""

from __future__ import annotations

import itertools
import os
import sys
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(REPO_ROOT / "test"))  # graph-test helpers (fuzzing) importable from every test
# DDS stays on this host; each test process gets its own band of domain ids.
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
_DOMAIN_IDS = itertools.count(1 + (os.getpid() % 20) * 5)


def data_dir() -> Path:
    return Path(os.environ.get("PVO_DATA_DIR", REPO_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def pvo_data() -> Path:
    """The real KITTI / Devon data; tests that need it skip with a reason when it is absent."""
    root = data_dir()
    if not (root / "kitti").is_dir():
        pytest.skip(f"real data not found at {root} (set PVO_DATA_DIR)")
    return root


@pytest.fixture(scope="session")
def sample_bag() -> Path:
    return REPO_ROOT / "bags" / "kitti06_sample"


@pytest.fixture
def domain_id() -> int:
    """A ROS domain id not used by any other test of this process (ids stay within 1..101)."""
    return 1 + (next(_DOMAIN_IDS) - 1) % 101


@pytest.fixture
def ros_context(domain_id: int):
    """A fresh rclpy context on its own domain id; shut down after the test."""
    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    yield context
    if context.ok():
        rclpy.shutdown(context=context)


@pytest.fixture
def ros_env(domain_id: int) -> dict[str, str]:
    """Environment for subprocesses that must join the test's ROS domain."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    return env
