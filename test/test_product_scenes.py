"""The product robot model's behaviour over real DDS (issue 41, part 5): brt_node filters with the HJ solver's
table for the scenes' map (a solver card: no learned model, the refinement path started from the target), or
with the bundled default (forward speeds, read by symmetry for this reversing base), and a simulated base
integrates the filtered command in real time with a disturbance ‖d‖ ≤ 0.1·|v|."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from test_brt_node import DOMAIN, ROOT, wait_for  # noqa: E402

from hjrno_ros.core import safety_filter  # noqa: E402
from hjrno_ros.core.dynamics import CarParams  # noqa: E402
from hjrno_ros.core.model_card import ModelCard  # noqa: E402
from hjrno_ros.ros.node import BrtNode  # noqa: E402
from hjrno_ros.ros.scene_driver import SceneBase  # noqa: E402
from hjrno_ros.studies import product_scenes  # noqa: E402

ROBOT = CarParams.product(v_min=-0.5)  # a base that reverses up to 0.5 m/s


@pytest.fixture(scope="module")
def solver_card(tmp_path_factory):
    stem = tmp_path_factory.mktemp("solver") / "product_solver"
    stem.with_suffix(".json").write_text(json.dumps(ModelCard.solver(ROBOT, cell=0.2, speeds=7, headings=16)))
    return stem


@pytest.fixture(scope="module", params=["solver", "default"])
def scene_node(request, solver_card):
    """brt_node over DDS for the scenes' base: on the solver card (the refinement path) or on the bundled default
    (a forward-speed FNO serving this reversing base by symmetry)."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN + 45)
    base = SceneBase(context, ROBOT)
    status: dict = {}
    probe = Node("scene_probe", context=context)
    probe.create_subscription(String, "brt/status", lambda m: status.update(json.loads(m.data)), 10)
    executor = SingleThreadedExecutor(context=context)
    for node in (base, probe):
        executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    params = ({"model_path": str(solver_card), "refine_horizon": 60.0, "refine_stage": 5.0, "refine_cpus": 1}
              if request.param == "solver" else {"model_path": str(ROOT / "models" / "default"), "v_min": ROBOT.v_min})
    source = "refined" if request.param == "solver" else "operator"
    brt = BrtNode(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    brt.start()
    executor.add_node(brt)
    try:
        base.place(product_scenes.SCENES[0].start)
        assert wait_for(lambda: status.get("value_source") == source, 240.0), status
        assert source == "operator" or status["refinement"]["settled"], status
        yield base, status
    finally:
        executor.shutdown(timeout_sec=2.0)
        for node in (brt, base, probe):
            node.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=2.0)


def test_a_solver_card_waits_for_a_settled_table(solver_card):
    """Until the solve from the target has settled the node fails closed (an unsettled table from the target
    under-approximates the tube), and a solver card without refine_horizon is refused with one line."""
    card = ModelCard.load(solver_card)
    assert card.kind == "solver" and card.dynamics == ROBOT
    from hjrno_ros.ros.model_files import load_model
    from hjrno_ros.ros.parameters import PARAMETERS

    cfg = {name: spec.default for name, spec in PARAMETERS.items()}
    with pytest.raises(ValueError, match="refine_horizon > 0"):
        load_model({**cfg, "model_path": str(solver_card), "refine_horizon": 0.0})
    with pytest.raises(ValueError, match="write the robot's limits into the card"):
        load_model({**cfg, "model_path": str(solver_card), "refine_horizon": 10.0, "v_max": 2.0})


@pytest.mark.parametrize("scene", product_scenes.SCENES, ids=[s.name for s in product_scenes.SCENES])
def test_scene_over_dds(scene_node, scene):
    base, status = scene_node
    base.place(scene.start)
    assert wait_for(lambda: status.get("robot") is not None and abs(status["robot"]["x"] - scene.start[0]) < 1e-3
                    and abs(status["robot"]["y"] - scene.start[1]) < 1e-3, 5.0), status
    states, outputs = base.run(scene)
    assert len(outputs) > 0.5 * scene.seconds / 0.05, (len(outputs), status)  # the node answered
    problems = product_scenes.judge(scene, states, outputs)
    assert not problems, (scene.expect, problems, status)
    if scene.name == "rest_stop":
        assert np.all(outputs == 0.0)  # the nominal stop passed as it is: nothing added


def test_scenes_offline_with_the_same_table_kind():
    """The same scenes without ROS (the numpy filter on a solved table), every filter mode: hjrno simulate's
    scenes."""
    from hjrno_ros.studies.product_scenes import solve_scene_table

    table = solve_scene_table(ROBOT, cell=0.2, speeds=7, headings=16)
    for mode in safety_filter.MODES:
        settings = safety_filter.FilterSettings(epsilon=0.1, mode=mode)
        for scene in product_scenes.SCENES:
            states, outputs = product_scenes.simulate(ROBOT, table, settings, scene)
            assert not product_scenes.judge(scene, states, outputs), (mode, scene.name)


def test_hjrno_simulate_runs_the_scenes(tmp_path):
    from hjrno_ros import cli

    assert cli.main(["simulate", "--scenes", "product", "--out", str(tmp_path)]) == 0
    table = (tmp_path / "scenes.md").read_text()
    assert table.count("| none |") == 3 * len(product_scenes.SCENES)
