"""The map-wide refinement: grid and window stitching, the staged warm-started solve, the child process.

Real parts: the bundled model (torch), real solves (JAX) on a one-window map (32 × 32 × 9 × 16), the child
process over real files.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import wait_for

from hjrno_ros.core import map_tiling
from hjrno_ros.learning.value_function import LearnedValueFunction
from hjrno_ros.ros.brt_node import refinement_process as mr
from hjrno_ros.truth import map_refinement
from hjrno_ros.truth.systems import DynamicDubinsCar

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "models" / "paper_cnn"


@pytest.fixture(scope="module")
def vf() -> LearnedValueFunction:
    return LearnedValueFunction(MODEL, device="cpu", threads=1)


def disk_v0(grid, centre=(1.0, 0.0), radius=1.5) -> np.ndarray:
    xy = grid.states()[:, :, 0, 0, :2]
    return (np.hypot(xy[..., 0] - centre[0], xy[..., 1] - centre[1]) - radius).astype(np.float32)


@pytest.fixture(scope="module")
def one_window(vf):
    """A 10 m map (one window) with a disk: grid, V0, the operator's warm start."""
    grid = map_tiling.map_grid(vf.grid, (-5.0, -5.0), (5.0, 5.0))
    v0 = disk_v0(grid)
    return grid, v0, map_refinement.warm_start(vf, v0, grid)


def test_map_grid_covers_the_map_and_window_nodes_are_grid_nodes(vf):
    grid = map_tiling.map_grid(vf.grid, (-3.0, 1.0), (15.2, 12.0))
    h = vf.grid.spacings[:2]
    assert np.allclose(grid.spacings[:2], h) and grid.shape[2:] == vf.grid.shape[2:]
    assert grid.lo[0] <= -3.0 and grid.hi[0] >= 15.2 and grid.lo[1] <= 1.0 and grid.hi[1] >= 12.0
    assert grid.hi[0] - grid.lo[0] < 15.2 + 3.0 + h[0] + 1e-9  # grown by less than one step
    assert map_tiling.map_grid(vf.grid, (-5.0, -5.0), (5.0, 5.0)) == vf.grid  # a window-sized map is the model's grid
    for axis in (0, 1):
        n, w = grid.shape[axis], vf.shape[axis]
        starts = map_tiling.window_starts(n, w)
        assert starts[0] == 0 and starts[-1] == n - w and np.all(np.diff(starts) <= w // 2)
        for i in starts:
            centre = grid.lo[axis] + (i + (w - 1) / 2) * h[axis]
            points = vf.window_points((centre, centre))
            nodes = points[:, 0, 0] if axis == 0 else points[0, :, 1]
            assert np.allclose(nodes, grid.axis(axis)[i:i + w], atol=1e-9)


def test_warm_start_of_one_window_is_the_operator_at_every_v_theta_node(vf, one_window):
    grid, v0, w = one_window
    vv, tt = np.meshgrid(grid.axis(2), grid.axis(3), indexing="ij")
    slices = vf.predict(v0, vv.ravel(), tt.ravel()).reshape(*vv.shape, *v0.shape)
    assert np.array_equal(w, np.moveaxis(slices, (0, 1), (2, 3)))


def test_warm_start_takes_each_node_from_the_window_with_the_nearest_centre(vf):
    grid = map_tiling.map_grid(vf.grid, (-5.0, -5.0), (12.0, 5.0))  # 54 x 32 nodes: windows at x nodes 0, 16, 22
    v0 = disk_v0(grid, centre=(4.0, 1.0))
    w = map_refinement.warm_start(vf, v0, grid)
    starts = map_tiling.window_starts(grid.shape[0], 32)
    assert starts == [0, 16, 22]
    iv, it = 4, 5
    for ix in (3, 20, 27, 40, 53):  # window centres at nodes 15.5, 31.5, 37.5: owners 0, 0, 1, 2, 2
        owner = starts[int(np.argmin([abs(ix - (s + 15.5)) for s in starts]))]
        expect = vf.predict(v0[owner:owner + 32], [grid.axis(2)[iv]], [grid.axis(3)[it]])[0]
        assert np.allclose(w[ix, :, iv, it], expect[ix - owner], atol=1e-5), ix  # batch size: float rounding
    with pytest.raises(ValueError, match="does not match"):
        map_refinement.warm_start(vf, v0[:-1], grid)


def test_refine_only_lowers_the_table_and_stops_at_the_horizon(vf, one_window):
    grid, v0, w = one_window
    target = map_refinement.broadcast_target(v0, grid)
    stages = list(map_refinement.refine(DynamicDubinsCar(vf.params), grid, target, w, horizon=2.0, stage=1.0))
    assert [round(s[0], 9) for s in stages] == [1.0, 2.0] or stages[-1][2]  # 2 stages unless settled early
    previous = np.minimum(w, v0[:, :, None, None])
    for _, table, _ in stages:
        assert table.shape == grid.shape and np.all(np.isfinite(table))
        assert np.all(table <= previous + 1e-5)  # the tube only lowers V
        previous = table
    assert float(np.abs(stages[-1][1] - np.minimum(w, v0[:, :, None, None])).max()) > 1e-3  # it did work
    with pytest.raises(ValueError, match="horizon > 0"):
        next(map_refinement.refine(DynamicDubinsCar(vf.params), grid, target, w, horizon=0.0, stage=1.0))


def wait_stage(r: mr.BackgroundRefinement, timeout: float = 240.0) -> mr.Stage | None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        stage = r.poll()
        if stage is not None or r.error:
            return stage
        time.sleep(0.2)
    return None


def test_child_cpus_leaves_the_node_a_core():
    assert mr.child_cpus(0, {0, 1}) == {1}
    assert mr.child_cpus(0, {0, 2, 5, 7}) == {2, 5, 7}
    assert mr.child_cpus(0, {3}) == {3}  # one core: shared, never none
    assert mr.child_cpus(2, {0, 1, 2, 3}) == {2, 3}
    assert mr.child_cpus(9, {0, 1}) == {0, 1}
    with pytest.raises(ValueError, match="cpus must be >= 0"):
        mr.BackgroundRefinement(-1)


def test_background_process_writes_the_in_process_result(vf, one_window):
    grid, v0, w = one_window
    target = map_refinement.broadcast_target(v0, grid)
    stages = map_refinement.refine(DynamicDubinsCar(vf.params), grid, target, w, horizon=1.0, stage=1.0)
    (_, expect, settled), = list(stages)
    r = mr.BackgroundRefinement()
    try:
        r.start(7, v0, grid, str(MODEL), horizon=1.0, stage=1.0)
        stage = wait_stage(r)
        assert stage is not None, r.error
        assert (stage.key, stage.grid, stage.horizon, stage.settled) == (7, grid, 1.0, settled)
        assert stage.cpus == len(mr.child_cpus(0, os.sched_getaffinity(0)))  # the child ran on those cores
        assert np.allclose(stage.values, expect, atol=1e-5)
        workdir = r._dir
        assert r.poll() is None  # each stage is read once
    finally:
        r.stop()
    assert not workdir.exists()


def test_a_failing_child_reports_one_line(tmp_path, one_window):
    grid, v0, _ = one_window
    r = mr.BackgroundRefinement()
    try:
        r.start(1, v0, grid, str(tmp_path / "no_model"), horizon=1.0, stage=1.0)
        assert wait_stage(r, 60.0) is None
        assert r.error.startswith("refinement process exited with 1: refinement failed: ") and "\n" not in r.error
    finally:
        r.stop()
    (tmp_path / mr.REQUEST).write_bytes(b"\x00" * 40)  # a truncated request
    child = [sys.executable, "-m", "hjrno_ros.ros.brt_node.refinement_process", str(tmp_path)]
    out = subprocess.run(child, capture_output=True,
                         text=True)
    assert out.returncode == 1 and "not a refinement file" in out.stderr and len(out.stderr.splitlines()) == 1
    assert not (tmp_path / mr.RESULT).exists()


def test_result_files_are_checked(tmp_path, one_window):
    grid, v0, w = one_window
    from safetensors.numpy import save_file

    bad = w.copy()
    bad[0, 0, 0, 0] = np.nan
    save_file({"values": bad}, str(tmp_path / "nan.safetensors"), metadata={"grid": json.dumps(grid.as_dict())})
    with pytest.raises(ValueError, match="NaN/Inf"):
        mr.read_table(tmp_path / "nan.safetensors")
    save_file({"values": w[:-1]}, str(tmp_path / "short.safetensors"), metadata={"grid": json.dumps(grid.as_dict())})
    with pytest.raises(ValueError, match="want"):
        mr.read_table(tmp_path / "short.safetensors")
    (tmp_path / "cut.safetensors").write_bytes((tmp_path / "short.safetensors").read_bytes()[:100])
    with pytest.raises(ValueError, match="not a refinement file"):
        mr.read_table(tmp_path / "cut.safetensors")


def test_the_child_dies_with_its_node_even_after_kill_9(tmp_path, one_window):
    """A node killed with -9 cannot stop its refinement child: the child notices it was orphaned, removes its
    work folder and exits; the next node's start removes folders of dead nodes."""
    import signal

    grid, v0, _ = one_window
    np.save(tmp_path / "v0.npy", v0)
    script = (
        "import json, sys, time\nimport numpy as np\n"
        "from hjrno_ros.core.grids import GridSpec\nfrom hjrno_ros.ros.brt_node import refinement_process as mr\n"
        f"grid = GridSpec.from_dict(json.loads({json.dumps(json.dumps(grid.as_dict()))!s}))\n"
        f"r = mr.BackgroundRefinement(1)\nr.start(1, np.load({str(tmp_path / 'v0.npy')!r}), grid, "
        f"{str(MODEL)!r}, horizon=600.0, stage=600.0)\n"
        "print(r._proc.pid, r._dir, flush=True)\ntime.sleep(120)\n")
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    child_pid, workdir = parent.stdout.readline().split()
    child_pid, workdir = int(child_pid), Path(workdir)
    assert workdir.is_dir() and workdir.name.startswith(f"hjrno_refine_{parent.pid}_")
    time.sleep(1.0)
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    end = time.monotonic() + 20.0
    while time.monotonic() < end:
        try:
            os.kill(child_pid, 0)
        except ProcessLookupError:
            break
        with open(f"/proc/{child_pid}/stat") as f:
            if f.read().rsplit(")", 1)[1].split()[0] == "Z":  # exited, not reaped yet
                break
        time.sleep(0.1)
    else:
        os.kill(child_pid, signal.SIGKILL)
        pytest.fail("the refinement child outlived its killed node")
    assert wait_for(lambda: not workdir.exists(), 5.0)
    stale = Path(tempfile.gettempdir()) / f"hjrno_refine_{parent.pid}_stale"
    stale.mkdir()
    mine = Path(tempfile.mkdtemp(prefix=f"hjrno_refine_{os.getpid()}_"))
    try:
        assert stale in mr.remove_stale_workdirs() and not stale.exists() and mine.exists()
    finally:
        shutil.rmtree(mine, ignore_errors=True)
