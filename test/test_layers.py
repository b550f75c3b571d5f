"""The tree's layers hold: the core imports no JAX, torch or rclpy; the node loads no JAX."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("jax", "hj_reachability", "torch", "rclpy")


def loaded_after(modules: list[str]) -> set[str]:
    """Which of HEAVY a fresh interpreter has imported after importing ``modules``."""
    code = (f"import sys\nfor m in {modules!r}: __import__(m)\n"
            f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    return set(out.stdout.split())


def test_core_imports_no_jax_torch_or_rclpy():
    core = [f"hjrno_ros.core.{p.stem}" for p in (ROOT / "hjrno_ros" / "core").glob("*.py") if p.stem != "__init__"]
    assert len(core) >= 7
    assert loaded_after(core) == set()


def test_node_modules_load_no_jax():
    ros = [f"hjrno_ros.ros.{p.stem}" for p in (ROOT / "hjrno_ros" / "ros").glob("*.py") if p.stem != "__init__"]
    loaded = loaded_after([*ros, "hjrno_ros.learning.value_function"])
    assert "rclpy" in loaded and "torch" in loaded  # the check sees imports
    assert "jax" not in loaded and "hj_reachability" not in loaded


@pytest.mark.parametrize("layer", ["truth", "datasets", "learning", "studies", "tools"])
def test_no_layer_below_ros_imports_rclpy(layer):
    modules = [f"hjrno_ros.{layer}.{p.stem}" for p in (ROOT / "hjrno_ros" / layer).glob("*.py")
               if p.stem != "__init__"]
    assert "rclpy" not in loaded_after(modules)
