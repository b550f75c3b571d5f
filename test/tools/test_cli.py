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
