"""Package layout that ROS 2 tooling relies on, and lint of the whole tree."""

import configparser
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_package_xml_declares_runtime_and_test_dependencies():
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.get("format") == "3" and root.findtext("name") == "hjrno_ros"
    exec_deps = {e.text for e in root.findall("exec_depend")}
    assert {"rclpy", "nav_msgs", "geometry_msgs", "std_msgs", "sensor_msgs", "diagnostic_msgs", "std_srvs"} <= exec_deps
    assert root.findall("test_depend")
    assert root.find("export/build_type").text == "ament_python"


def test_ament_python_layout():
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    assert cfg["develop"]["script_dir"] == "$base/lib/hjrno_ros"
    assert cfg["install"]["install_scripts"] == "$base/lib/hjrno_ros"
    assert (ROOT / "resource" / "hjrno_ros").is_file()
    for folder in ("hjrno_ros", "models", "config", "test"):
        assert (ROOT / folder).is_dir()


def test_only_the_ros_layer_imports_rclpy():
    for path in (ROOT / "hjrno_ros").rglob("*.py"):
        if path.relative_to(ROOT / "hjrno_ros").parts[0] == "ros":
            continue
        text = path.read_text()
        assert "import rclpy" not in text and "from rclpy" not in text, path


def test_console_script_is_installed():
    exe = Path(sys.executable).parent / "hjrno"
    assert exe.exists() or shutil.which("hjrno"), "run `make setup` (pip install -e .)"
    out = subprocess.run([str(exe) if exe.exists() else "hjrno", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "solve" in out.stdout


def test_ruff_lint_is_clean():
    ruff = Path(sys.executable).parent / "ruff"
    out = subprocess.run([str(ruff), "check", str(ROOT)], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
