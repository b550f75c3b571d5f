"""colcon builds the package into an ament install tree, and ``lib/hjrno_ros/brt_node`` runs from it.

What ``ros2 run hjrno_ros brt_node`` relies on: the ament index marker, package.xml, the console
script under ``lib/<package>``, config and models under ``share/<package>``; ``ros2 launch`` and RViz
find the launch file and the RViz config under ``share/<package>/launch`` and ``.../rviz``.  The installed
executable is started the way a sourced workspace would (install site-packages on PYTHONPATH,
AMENT_PREFIX_PATH), with the installed params file, seen on DDS, and stopped with SIGINT.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("colcon_core")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from std_msgs.msg import String  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DOMAIN = 51 + os.getpid() % 50  # apart from test_brt_node's 1..50; <= 101 avoids ephemeral ports
PY = f"python{sys.version_info.major}.{sys.version_info.minor}"

pytestmark = pytest.mark.real_time  # runs a node over DDS in real time (test/conftest.py)


def model_for_startup(tmp: Path) -> Path:
    """The bundled model, else an untrained tiny FNO (start-up only needs a loadable car model)."""
    from hjrno_ros.learning import checkpoint

    bundled = ROOT / "models" / "default"
    if checkpoint.paths(bundled)[1].is_file():
        return bundled
    from hjrno_ros.core.dynamics import CarParams
    from hjrno_ros.core.grids import car_grid
    from hjrno_ros.learning.operators import build_model
    from hjrno_ros.learning.slices import InputSpec

    model = build_model("fno", in_channels=4, width=8, modes=4, n_layers=2)
    card = {"kind": "fno", "config": model.config, "inputs": InputSpec("car", 5.0).as_dict(),
            "grid": car_grid((20, 20, 5, 8)).as_dict(), "dynamics": CarParams().as_dict(), "epsilon": None}
    checkpoint.save(tmp / "model", {f"model.{k}": v for k, v in model.state_dict().items()}, card)
    return tmp / "model"


def test_colcon_build_installs_a_runnable_brt_node(tmp_path):
    build = subprocess.run(
        [sys.executable, "-m", "colcon", "--log-base", str(tmp_path / "log"), "build", "--base-paths", str(ROOT),
         "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert build.returncode == 0, build.stdout[-2000:] + build.stderr[-2000:]
    prefix = tmp_path / "install" / "hjrno_ros"
    share = prefix / "share" / "hjrno_ros"
    exe = prefix / "lib" / "hjrno_ros" / "brt_node"
    for path in (exe, prefix / "share" / "ament_index" / "resource_index" / "packages" / "hjrno_ros",
                 share / "package.xml", share / "config" / "brt_node.yaml",
                 share / "launch" / "brt_node.launch.py", share / "rviz" / "brt_node.rviz"):
        assert path.is_file(), path
    assert os.access(exe, os.X_OK)
    bundled = [f for f in [*ROOT.glob("models/*.json"), *ROOT.glob("models/*.safetensors"), *ROOT.glob("models/*.onnx")]
               if ".train." not in f.name]
    assert bundled, "models/ should ship the default model"
    for model_file in bundled:
        assert (share / "models" / model_file.name).is_file(), model_file
    assert not list((share / "models").glob("*.train.*"))  # training state is not installed
    site = prefix / "lib" / PY / "site-packages"
    assert (site / "hjrno_ros" / "ros" / "brt_node" / "node.py").is_file()

    model = model_for_startup(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]),
           "AMENT_PREFIX_PATH": os.pathsep.join([str(prefix), os.environ.get("AMENT_PREFIX_PATH", "")]),
           "ROS_DOMAIN_ID": str(DOMAIN), "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([str(exe), "--ros-args", "--params-file", str(share / "config" / "brt_node.yaml"),
                             "-p", f"model_path:={model}"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN)
    node = Node("colcon_probe", context=context)
    status: list[dict] = []
    node.create_subscription(String, "brt/status", lambda m: status.append(json.loads(m.data)), 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        end = time.monotonic() + 40.0
        while time.monotonic() < end and not status and proc.poll() is None:
            executor.spin_once(timeout_sec=0.1)
        assert status, f"no status from the installed node (exit {proc.poll()})"
        end = time.monotonic() + 10.0  # graph discovery can lag the first message on a busy machine
        while time.monotonic() < end and "brt_node" not in node.get_node_names():
            executor.spin_once(timeout_sec=0.1)
        assert "brt_node" in node.get_node_names()
        assert status[-1]["state"] == "fail_closed" and status[-1]["reason"].startswith("no map")
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=10.0)
        assert proc.returncode == 0, out[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
