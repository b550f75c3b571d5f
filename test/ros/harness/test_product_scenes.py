"""The product models' behaviour over real DDS: brt_node filters for the product car with the HJ solver's table
for the scenes' map (a solver card: no learned model, the refinement path started from the target), and for the
differential drive with the bundled default (forward speeds, read by symmetry for this reversing base); a simulated
base integrates the filtered command in real time with a disturbance ‖d‖ ≤ 0.1·|v|."""

from __future__ import annotations

import dataclasses
import json
import threading

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from dds_driver import DOMAIN, ROOT, wait_for  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from hjrno_ros.core.model_card import ModelCard  # noqa: E402
from hjrno_ros.ros.brt_node.node import BrtNode  # noqa: E402
from hjrno_ros.ros.harness import scene_driver  # noqa: E402
from hjrno_ros.studies import product_scenes  # noqa: E402

CAR, CAR_SCENES = product_scenes.ROBOTS["car"]  # a base that reverses up to 0.5 m/s
DIFF_DRIVE, DIFF_DRIVE_SCENES = product_scenes.ROBOTS["diff_drive"]


@pytest.fixture(scope="module")
def solver_card(tmp_path_factory):
    stem = tmp_path_factory.mktemp("solver") / "product_solver"
    stem.with_suffix(".json").write_text(json.dumps(ModelCard.solver(CAR, cell=0.2, speeds=7, headings=16)))
    return stem


@pytest.fixture(scope="module", params=["car", "diff_drive"])
def scene_node(request, solver_card):
    """brt_node over DDS for the scenes' base: the car on the solver card (the refinement path), or the differential
    drive on the bundled default (a forward-speed FNO serving this reversing base by symmetry)."""
    robot = CAR if request.param == "car" else DIFF_DRIVE
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN + 45)
    base = scene_driver.scene_base(context, robot)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(base)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    params = ({"model_path": str(solver_card), "refine_horizon": 60.0, "refine_stage": 5.0, "refine_cpus": 1,
               "robot_model": "car"}
              if request.param == "car" else {"model_path": str(ROOT / "models" / "default"), "v_min": robot.v_min,
                                              "a_max": robot.a_max, "omega_max": robot.omega_max,
                                              "v_max": robot.v_max})
    source = "refined" if request.param == "car" else "operator"
    brt = BrtNode(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    brt.start()
    executor.add_node(brt)
    try:
        scene_driver.place(base, product_scenes.SCENES[0].start)
        assert wait_for(lambda: base.log.status.get("value_source") == source, 240.0), base.log.status
        assert source == "operator" or base.log.status["refinement"]["settled"], base.log.status
        yield base, request.param
    finally:
        executor.shutdown(timeout_sec=2.0)
        for node in (brt, base):
            node.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=2.0)


def test_a_solver_card_waits_for_a_settled_table(solver_card):
    """Until the solve from the target has settled the node fails closed (an unsettled table from the target
    under-approximates the tube), and a solver card without refine_horizon is refused with one line."""
    card = ModelCard.load(solver_card)
    assert card.kind == "solver" and card.dynamics == CAR
    from hjrno_ros.ros.brt_node.config import NodeConfig
    from hjrno_ros.ros.brt_node.value_sources import load_model

    with pytest.raises(ValueError, match="set robot_model: car"):  # the default robot_model is diff_drive
        load_model(NodeConfig(model_path=str(solver_card), refine_horizon=10.0))
    car = {"robot_model": "car", "model_path": str(solver_card)}
    with pytest.raises(ValueError, match="refine_horizon > 0"):
        load_model(NodeConfig(**car, refine_horizon=0.0))
    with pytest.raises(ValueError, match="write the robot's limits into the card"):
        load_model(NodeConfig(**car, refine_horizon=10.0, v_max=2.0))


def test_every_value_source_has_the_members_the_node_reads(solver_card):
    """The learned operator, the same at another robot's size and a solver card all carry ValueSource's members;
    only the solver card does not predict (the node waits for its solver), and asking it to raises."""
    import typing

    from hjrno_ros.core.scaled_values import ScaledValueFunction, covered_scaling
    from hjrno_ros.core.value_source import ValueSource
    from hjrno_ros.learning.value_function import LearnedValueFunction
    from hjrno_ros.ros.brt_node.value_sources import SolverGrid

    learned = LearnedValueFunction(ROOT / "models" / "default", device="cpu")
    small = dataclasses.replace(learned.params, v_max=0.5, v_min=-0.5, omega_max=1.0, a_max=0.5)
    scaling = covered_scaling(learned.params, small, learned.card.inputs.get("param_ranges"))
    scaled = ScaledValueFunction(learned, scaling, small)
    solver = SolverGrid(ModelCard.load(solver_card))
    members = [*typing.get_type_hints(ValueSource), "window_points", "local_table"]
    for source, predicts in ((learned, True), (scaled, True), (solver, False)):
        assert all(hasattr(source, name) for name in members), (source, members)
        assert source.predicts is predicts
    assert scaled.whole_table and not solver.whole_table
    with pytest.raises(TypeError, match="no operator"):
        solver.local_table(np.zeros(solver.shape), (0.0, 0.0), 0.0, 0.0)


SCENE_NAMES = sorted({s.name for s in CAR_SCENES + DIFF_DRIVE_SCENES})


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_scene_over_dds(scene_node, name):
    base, robot = scene_node
    scenes = {s.name: s for s in (CAR_SCENES if robot == "car" else DIFF_DRIVE_SCENES)}
    if name not in scenes:
        return  # a scene of the other robot model
    scene = scenes[name]
    scene_driver.place(base, scene.start)

    def at_start() -> bool:
        at = base.log.status.get("robot")
        return at is not None and abs(at["x"] - scene.start[0]) < 1e-3 and abs(at["y"] - scene.start[1]) < 1e-3

    assert wait_for(at_start, 5.0), base.log.status
    stops = base.log.status["counts"]["stops"]
    states, outputs = scene_driver.run(base, scene)
    status = base.log.status
    assert len(outputs) > 0.5 * scene.seconds / 0.05, (len(outputs), status)  # the node answered
    problems = product_scenes.judge(scene, states, outputs)
    assert not problems, (scene.expect, problems, status)
    if scene.name == "rest_stop":
        assert np.all(outputs == 0.0)  # the nominal stop passed as it is: nothing added
    if robot == "diff_drive":
        assert status["counts"]["stops"] == stops  # the robot's own motion never fails closed
