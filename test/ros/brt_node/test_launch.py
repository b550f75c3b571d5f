"""The launch file and the RViz config, checked without the launch packages (not on PyPI).

``launch/brt_node.launch.py`` must compile and name what exists: the package, its console script,
the node name the params file is keyed by, brt_node's parameters and default topic names, Nav2's
lifecycle manager with ``bond_timeout`` 0 and brt_node in ``node_names``.  The file is read with
``ast``; ``ros2 launch`` itself only runs where ROS 2 and Nav2 are installed.
"""

from __future__ import annotations

import ast
import py_compile
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")

from hjrno_ros.ros.brt_node.parameters import PARAMETERS  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
LAUNCH = ROOT / "launch" / "brt_node.launch.py"
RVIZ = ROOT / "rviz" / "brt_node.rviz"
ARGUMENTS = {"params_file", "use_sim_time", "autostart", "namespace", "log_level", "cmd_vel_in", "cmd_vel_out",
             "map", "odom"}


def value(node: ast.AST, names: dict | None = None):
    """A keyword value: literals as Python values, LaunchConfiguration('x') as ("arg", "x"), other calls as
    (name, [args]), lists and dicts element-wise; a variable as what ``names`` says it holds, else
    ("name", id)."""
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        return (names or {}).get(node.id, ("name", node.id))
    if isinstance(node, ast.List | ast.Tuple):
        return [value(e, names) for e in node.elts]
    if isinstance(node, ast.Dict):
        return {value(k, names): value(v, names) for k, v in zip(node.keys, node.values, strict=True)}
    if isinstance(node, ast.Call):
        name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
        if name == "LaunchConfiguration":
            return ("arg", node.args[0].value)
        return (name, [value(a, names) for a in node.args])
    return ("expr", ast.unparse(node))


def calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == name]


def launch_configurations(tree: ast.AST) -> dict:
    """Variables assigned a LaunchConfiguration: name -> ("arg", argument)."""
    return {n.targets[0].id: value(n.value) for n in ast.walk(tree) if isinstance(n, ast.Assign)
            and isinstance(n.targets[0], ast.Name) and isinstance(n.value, ast.Call)
            and getattr(n.value.func, "id", "") == "LaunchConfiguration"}


def keywords(call: ast.Call, names: dict | None = None) -> dict:
    return {k.arg: value(k.value, names) for k in call.keywords}


@pytest.fixture(scope="module")
def tree() -> ast.Module:
    return ast.parse(LAUNCH.read_text(), str(LAUNCH))


def test_launch_file_compiles(tmp_path):
    py_compile.compile(str(LAUNCH), cfile=str(tmp_path / "launch.pyc"), doraise=True)


def test_launch_file_starts_the_packages_brt_node_inactive(tree):
    names = launch_configurations(tree)
    nodes = {keywords(c)["name"]: keywords(c, names) for c in calls(tree, "Node")}
    assert set(nodes) == {"brt_node", "lifecycle_manager_brt"}
    brt = nodes["brt_node"]
    assert brt["package"] == "hjrno_ros" and brt["executable"] == "brt_node"
    setup = ast.parse((ROOT / "setup.py").read_text())
    entry = "brt_node = hjrno_ros.ros.brt_node.main:main"
    assert any(isinstance(n, ast.Constant) and n.value == entry for n in ast.walk(setup))
    from hjrno_ros.ros.brt_node.node import NODE_NAME

    assert brt["name"] == NODE_NAME
    params_file, overrides = brt["parameters"]
    assert params_file == ("ParameterFile", [("arg", "params_file")])
    assert overrides["autostart"] is False and overrides["use_sim_time"] == ("arg", "use_sim_time")
    assert set(overrides) - {"use_sim_time"} <= set(PARAMETERS), "overrides name parameters brt_node does not have"
    # the remappings act on brt_node's default topic names
    remap = {src: dst for src, dst in value(next(n.value for n in ast.walk(tree) if isinstance(n, ast.Assign)
                                                  and getattr(n.targets[0], "id", "") == "remappings"))}
    defaults = {PARAMETERS[p].default: arg for p, arg in (("cmd_vel_in_topic", "cmd_vel_in"),
                                                          ("cmd_vel_out_topic", "cmd_vel_out"),
                                                          ("map_topic", "map"), ("odom_topic", "odom"))}
    assert remap == {topic: ("arg", arg) for topic, arg in defaults.items()}
    assert brt["remappings"] == ("name", "remappings")
    assert brt["namespace"] == nodes["lifecycle_manager_brt"]["namespace"] == ("arg", "namespace")


def test_lifecycle_manager_without_bond(tree):
    names = launch_configurations(tree)
    manager = next(keywords(c, names) for c in calls(tree, "Node") if keywords(c)["name"] == "lifecycle_manager_brt")
    assert manager["package"] == "nav2_lifecycle_manager" and manager["executable"] == "lifecycle_manager"
    params = {k: v for d in manager["parameters"] for k, v in d.items()}
    assert params == {"use_sim_time": ("arg", "use_sim_time"), "autostart": ("arg", "autostart"),
                      "node_names": ["brt_node"], "bond_timeout": 0.0}


def test_launch_arguments_are_declared_and_default_to_the_installed_params(tree):
    declared = {keywords(c).get("name") or value(c.args[0]): c for c in calls(tree, "DeclareLaunchArgument")}
    assert set(declared) == ARGUMENTS
    used = {v.args[0].value for v in calls(tree, "LaunchConfiguration")}
    assert used == ARGUMENTS
    default = keywords(declared["params_file"])["default_value"]
    assert default == ("os.path.join", [("name", "share"), "config", "brt_node.yaml"])
    share = next(c for c in calls(tree, "get_package_share_directory"))
    assert value(share.args[0]) == "hjrno_ros"
    params = yaml.safe_load((ROOT / "config" / "brt_node.yaml").read_text())
    assert set(params) == {"brt_node"}  # keyed by the node's name
    assert set(params["brt_node"]["ros__parameters"]) <= set(PARAMETERS)
    assert keywords(declared["autostart"])["default_value"] == "true"
    assert keywords(declared["use_sim_time"])["default_value"] == "false"
    assert keywords(declared["cmd_vel_in"])["default_value"] == PARAMETERS["cmd_vel_in_topic"].default


def test_rviz_config_shows_the_map_the_value_grid_and_the_robot():
    config = yaml.safe_load(RVIZ.read_text())
    manager = config["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "map"
    displays = manager["Displays"]
    by_class: dict[str, list[dict]] = {}
    for d in displays:
        by_class.setdefault(d["Class"], []).append(d)
    maps = {d["Topic"]["Value"]: d for d in by_class["rviz_default_plugins/Map"]}
    assert set(maps) == {"/" + PARAMETERS["map_topic"].default, "/" + PARAMETERS["value_grid_topic"].default}
    value_grid = maps["/" + PARAMETERS["value_grid_topic"].default]
    assert value_grid["Color Scheme"] == "costmap"
    for d in maps.values():  # brt_node and map_server publish these latched
        assert d["Topic"]["Durability Policy"] == "Transient Local" and d["Topic"]["Reliability Policy"] == "Reliable"
    (odom,) = by_class["rviz_default_plugins/Odometry"]
    assert odom["Topic"]["Value"] == "/" + PARAMETERS["odom_topic"].default
    assert "rviz_default_plugins/TF" in by_class and "rviz_default_plugins/Grid" in by_class
    assert all(d["Enabled"] for d in displays)


def test_setup_installs_launch_and_rviz():
    setup = (ROOT / "setup.py").read_text()
    assert '"/launch", glob("launch/*.launch.py")' in setup and '"/rviz", glob("rviz/*.rviz")' in setup
