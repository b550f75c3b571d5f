"""The tree's layers hold (docs/design.md, "Layers").

Every ``hjrno_ros`` import, at the top of a module or inside a function, points down the layer order or
within its own layer; module imports form no cycle; the core loads no JAX, torch or rclpy; the node loads no
JAX and, of this package, only the core, the learned value source (with the operators it runs) and itself.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "hjrno_ros"
HEAVY = ("jax", "hj_reachability", "torch", "rclpy")
# Bottom to top; a module may import its own layer and the ones before it.  ``ros.brt_node`` (the node)
# sits below ``ros.harness`` (the simulated robots and drivers that exercise it).
LAYERS = ("base", "core", "inference", "truth", "datasets", "learning", "studies", "ros", "ros.brt_node", "ros.harness",
          "tools", "cli")
# The learned value source and what runs it: onnxruntime, or torch's operators, checkpoints and input slices (no
# training; torch only for a card without an ONNX export).
NODE_MAY_LOAD = ("hjrno_ros.core", "hjrno_ros.inference", "hjrno_ros.ros.brt_node", "hjrno_ros.learning.value_function",
                 "hjrno_ros.learning.checkpoint", "hjrno_ros.learning.operators", "hjrno_ros.learning.slices")


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def layer(module: str) -> str:
    """The layer of ``hjrno_ros.<...>``: the longest entry of LAYERS its path starts with."""
    rest = module.removeprefix("hjrno_ros").lstrip(".")
    best = "base"  # hjrno_ros itself and its version helper
    for name in LAYERS:
        if rest == name or rest.startswith(name + "."):
            best = name if len(name) > len(best) or best == "base" else best
    return best


def imports(module: str, path: Path, top_only: bool = False) -> set[str]:
    """The ``hjrno_ros`` modules that ``module`` imports (resolved relative imports included)."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_only else ast.walk(tree)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            known = modules()
            found |= {f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names}
    return {m for m in found if m == "hjrno_ros" or m.startswith("hjrno_ros.")}


def upward_imports() -> list[str]:
    order = {name: i for i, name in enumerate(LAYERS)}
    bad = []
    for module, path in modules().items():
        for target in sorted(imports(module, path)):
            if order[layer(target)] > order[layer(module)]:
                bad.append(f"{module} ({layer(module)}) imports {target} ({layer(target)})")
    return bad


def test_layer_of_a_module_is_its_longest_matching_package():
    assert layer("hjrno_ros") == "base"
    assert layer("hjrno_ros.core.grids") == "core"
    assert layer("hjrno_ros.ros.brt_node.node") == "ros.brt_node"
    assert layer("hjrno_ros.ros.harness.spin") == "ros.harness"
    assert layer("hjrno_ros.cli") == "cli"


def test_every_module_belongs_to_a_layer():
    unplaced = [m for m in modules() if layer(m) == "base" and m not in ("hjrno_ros", "hjrno_ros.versions")]
    assert unplaced == [], "modules outside every layer of LAYERS"


def test_no_module_imports_a_layer_above_its_own():
    assert len(modules()) > 40  # the walk sees the tree
    assert upward_imports() == []


def test_module_imports_form_no_cycle():
    graph = {m: imports(m, p, top_only=True) & modules().keys() for m, p in modules().items()}
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(m: str, trail: list[str]) -> None:
        state[m] = 1
        for n in sorted(graph[m]):
            if state.get(n) == 1 and n != m and not m.startswith(n + "."):  # a package's own __init__ is no cycle
                cycles.append([*trail[trail.index(n):], n] if n in trail else [m, n])
            elif n not in state:
                visit(n, [*trail, n])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    assert cycles == []


def loaded_after(names: list[str], prefix: str = "") -> set[str]:
    """Modules a fresh interpreter holds after importing ``names``: HEAVY ones, or those starting with prefix."""
    want = f"m.startswith({prefix!r})" if prefix else f"m in {HEAVY!r}"
    code = (f"import sys\nfor m in {names!r}: __import__(m)\n"
            f"print(' '.join(m for m in sys.modules if {want}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    return set(out.stdout.split())


def package_modules(package: str) -> list[str]:
    return [m for m in modules() if m.startswith(f"hjrno_ros.{package}.") or m == f"hjrno_ros.{package}"]


def test_core_imports_no_jax_torch_or_rclpy():
    core = package_modules("core")
    assert len(core) >= 7
    assert loaded_after(core) == set()


def test_node_loads_no_jax():
    loaded = loaded_after([*package_modules("ros.brt_node"), "hjrno_ros.learning.value_function"])
    assert "rclpy" in loaded and "torch" in loaded  # the check sees imports
    assert "jax" not in loaded and "hj_reachability" not in loaded


def test_node_loads_only_the_core_its_value_sources_and_itself():
    ours = loaded_after([*package_modules("ros.brt_node"), "hjrno_ros.learning.value_function"], prefix="hjrno_ros.")
    assert "hjrno_ros.ros.brt_node.node" in ours  # the check sees imports
    outside = sorted(m for m in ours if not any(m == p or m.startswith(p + ".") for p in NODE_MAY_LOAD)
                     and m not in ("hjrno_ros", "hjrno_ros.ros", "hjrno_ros.learning"))
    assert outside == [], "the node loads modules beyond the core, its value sources and itself"


@pytest.mark.parametrize("package", ["truth", "datasets", "learning", "studies", "tools"])
def test_no_package_below_ros_loads_rclpy(package):
    assert "rclpy" not in loaded_after(package_modules(package))


def test_the_node_runs_its_bundled_default_without_torch_or_scipy():
    """The node's modules and its bundled default loaded the node's way (an ONNX export in the card: onnxruntime),
    one whole table predicted from a map's signed distance and a scan's obstacles and read with its gradient:
    neither torch nor any part of scipy imported (requirements-node.txt has none)."""
    code = ("import sys\nimport numpy as np\n"
            "from hjrno_ros.core import geometry\n"
            "from hjrno_ros.core.point_obstacles import PointObstacles\n"
            "from hjrno_ros.ros.brt_node.node import BrtNode\n"
            "from hjrno_ros.ros.brt_node.config import NodeConfig\n"
            "from hjrno_ros.ros.brt_node.value_sources import load_model\n"
            "card, vf, stem = load_model(NodeConfig())\n"
            "occupancy = np.zeros((200, 200), np.int8); occupancy[90:110, 120:140] = 100\n"
            "sd = geometry.occupancy_signed_distance(occupancy, 0.05)\n"
            "points = vf.window_points((5.0, 5.0))\n"
            "v0 = np.minimum(geometry.sample_walled(sd, (0.0, 0.0), 0.05, points),\n"
            "                PointObstacles(np.array([[5.5, 5.0], [5.5, 5.2]]), 0.05).distance(points))\n"
            "window = vf.local_table(v0.astype(np.float32), (5.0, 5.0), 0.5, 0.0)\n"
            "value, gradient = window.value_and_gradient(np.array([5.1, 5.2, 0.3, 1.0]))\n"
            "print(type(vf).__name__, bool(np.isfinite(v0).all()), bool(np.isfinite(gradient).all()),\n"
            "      'torch' in sys.modules, sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')[:3])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.split() == ["OperatorValues", "True", "True", "False", "[]"], out.stdout
