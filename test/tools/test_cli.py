"""The hjrno command line, run as a user would: real processes, real files."""

import json
import subprocess
import sys

import h5py
import pytest

from hjrno_ros.datasets.h5store import read_solution, write_solution
from hjrno_ros.truth.problems import disk


def hjrno(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "hjrno_ros.cli", *args], capture_output=True, text=True, cwd=cwd)


def test_solve_writes_value_table_report_and_figure(tmp_path):
    out = hjrno("solve", "--scenario", "disk", "--grid", "24,24,7,12", "--out", str(tmp_path), "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["report"]["converged"] and result["peak_rss_mb"] > 0
    grid, target, value, meta = read_solution(tmp_path / "disk.h5")
    assert grid.shape == (24, 24, 7, 12) and value.shape == target.shape
    assert (value <= target + 1e-5).all()
    assert meta["report"]["converged"] and meta["params"]["a_max"] == 1.0 and meta["versions"]["hj-reachability"]
    assert (tmp_path / "disk.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unconverged_solve_exits_3_and_says_so(tmp_path):
    out = hjrno("solve", "--scenario", "disk", "--grid", "24,24,7,12", "--max-horizon", "2", "--out", str(tmp_path),
                "--no-plot", "--quiet")
    assert out.returncode == 3
    assert "NOT converged" in out.stdout


@pytest.mark.parametrize("args, message", [
    (["--scenario", "moon"], "unknown problem"),
    (["--grid", "24,24,7"], "4 axes"),
    (["--grid", "a,b"], "grid must look like"),
])
def test_bad_arguments_give_one_line_errors(tmp_path, args, message):
    out = hjrno("solve", "--out", str(tmp_path), *args)
    assert out.returncode == 2
    assert message in out.stderr
    assert "Traceback" not in out.stderr
    assert not list(tmp_path.glob("*.h5"))


def test_bench_model_is_for_the_node_benchmark_only(tmp_path):
    out = hjrno("bench", "solver", "--model", "models/default", "--out", str(tmp_path))
    assert out.returncode == 2 and "node benchmark only" in out.stderr and "Traceback" not in out.stderr
    assert not list(tmp_path.iterdir())


def test_corrupt_or_foreign_files_are_refused(tmp_path):
    truncated = tmp_path / "bad.h5"
    truncated.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    with pytest.raises(ValueError, match="unreadable"):
        read_solution(truncated)
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = [1, 2, 3]
    with pytest.raises(ValueError, match="not an hjrno solution"):
        read_solution(foreign)


def test_failed_write_keeps_the_previous_file(tmp_path):
    problem = disk((8, 8, 4, 6))
    path = tmp_path / "s.h5"
    write_solution(path, problem.grid, problem.target, problem.target, {"n": 1})
    with pytest.raises(TypeError):
        write_solution(path, problem.grid, problem.target, problem.target, {"n": object()})  # not JSON
    assert read_solution(path)[3] == {"n": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["s.h5"]


def test_train_refuses_a_missing_base_model_before_writing(ci_data, tmp_path):
    out = hjrno("train", "--data", str(ci_data), "--epochs", "1", "--angle-pair-weight", "1", "--init",
                str(tmp_path / "none"), "--out", str(tmp_path / "m"), "--quiet")
    assert out.returncode == 2 and "none.json not found" in out.stderr and "Traceback" not in out.stderr
    assert not list(tmp_path.glob("m*"))


def test_agents_solves_for_a_robot_given_by_its_limits_and_the_node_takes_it(tmp_path):
    """``hjrno agents`` with the node's own limits (no named robot): a table the node with those limits loads, whose
    card rebuilds it; a node with other limits refuses it with the command for its own; missing limits: one line."""
    from hjrno_ros.core.dynamics import DiffDriveParams
    from hjrno_ros.core.tracked_agents import read_agent_table
    from hjrno_ros.ros.brt_node.config import NodeConfig
    from hjrno_ros.ros.brt_node.value_sources import load_agent_table

    stem = tmp_path / "agents_mine"
    limits = ["--v-min", "-0.5", "--v-max", "1", "--a-max", "1", "--omega-max", "2", "--radius", "0.25"]
    small = ["--speeds", "0,0.5", "--deviation", "0.1", "--cell", "0.3", "--v-nodes", "7", "--theta-nodes", "8",
             "--cap", "0.5", "--margin", "0.3"]  # reverses at half its top speed: 7 nodes put one at v = 0
    out = hjrno("agents", *limits, *small, "--out", str(stem))
    assert out.returncode == 0, out.stdout + out.stderr
    card = json.loads(stem.with_suffix(".json").read_text())
    assert card["robot"]["v_min"] == -0.5 and card["robot"]["radius"] == 0.25 and card["radius"] == pytest.approx(0.45)
    assert card["reproduce"].startswith("hjrno agents --v-min -0.5 --v-max 1 --a-max 1 --omega-max 2 "
                                        "--tracking-error 0.1 --radius 0.25 --out")
    mine = DiffDriveParams(a_max=1.0, omega_max=2.0, v_min=-0.5, v_max=1.0)
    table = load_agent_table(NodeConfig(agent_table=str(stem), footprint_radius=0.25), mine)
    assert table is not None and table.robot == read_agent_table(stem).robot
    faster = DiffDriveParams(a_max=1.0, omega_max=2.0, v_min=-0.5, v_max=1.2)
    with pytest.raises(ValueError, match=r"hjrno agents --v-min -0.5 --v-max 1.2 .* --radius 0.25 --out STEM"):
        load_agent_table(NodeConfig(agent_table=str(stem), footprint_radius=0.25), faster)
    missing = hjrno("agents", "--v-max", "0.5", "--out", str(tmp_path / "other"))
    assert missing.returncode == 2 and "missing --v-min --a-max --omega-max --radius" in missing.stdout
    assert not (tmp_path / "other.json").exists()
