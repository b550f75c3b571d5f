"""The node's background refinement process: a nice-19 child that refines the map's value table
(:mod:`hjrno_ros.truth.map_refinement`, JAX only in that child) and the files through which it talks to the node.

* :class:`BackgroundRefinement` (the node's side): at most one child at a time, on the cores of
  :func:`child_cpus`, polled for each stage's table.
* :func:`main`: the child: it reads a request file and writes each stage's table over the same output file,
  atomically.
Axis order everywhere: V[ix, iy, iv, iθ] (docs/design.md, "Conventions").
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.grids import GridSpec

REQUEST, RESULT = "request.safetensors", "value.safetensors"
CHILD_NICE = 19  # the solver process yields every core to the node


def write_request(path: Path, v0: np.ndarray, grid: GridSpec, model: str, horizon: float, stage: float) -> None:
    from safetensors.numpy import save_file

    meta = {"grid": json.dumps(grid.as_dict()), "model": str(model), "horizon": repr(float(horizon)),
            "stage": repr(float(stage))}
    save_file({"v0": np.ascontiguousarray(v0, np.float32)}, str(path), metadata=meta)


def read_table(path: Path) -> tuple[GridSpec, np.ndarray, dict]:
    """A request's or a result's (grid, array, metadata); ValueError with one line if it is not one."""
    from safetensors import safe_open

    try:
        with safe_open(str(path), "numpy") as f:
            meta = f.metadata() or {}
            (name,) = f.keys()
            array = f.get_tensor(name)
        grid = GridSpec.from_dict(json.loads(meta["grid"]))
    except Exception as err:  # a truncated, foreign or incomplete file
        raise ValueError(f"{path.name}: not a refinement file ({type(err).__name__}: {err})") from None
    want = grid.shape[:2] if name == "v0" else grid.shape
    if array.shape != tuple(want) or not np.all(np.isfinite(array)):
        raise ValueError(f"{path.name}: {name} has shape {array.shape} (want {tuple(want)}) or NaN/Inf values")
    return grid, array, meta


def run_request(workdir: Path) -> None:
    """Child process body: read ``workdir/request``, write each stage's table to ``workdir/value``."""
    from safetensors.numpy import save_file

    from hjrno_ros.core.model_card import ModelCard
    from hjrno_ros.learning.value_function import LearnedValueFunction
    from hjrno_ros.truth.map_refinement import broadcast_target, refine, warm_start
    from hjrno_ros.truth.systems import robot_system

    grid, v0, meta = read_table(workdir / REQUEST)
    card = ModelCard.load(meta["model"])
    start = time.perf_counter()
    target = broadcast_target(v0, grid)
    if card.kind == "solver":  # no operator: the solve starts from the target itself
        params, initial = card.dynamics, target
    else:
        vf = LearnedValueFunction(meta["model"], threads=1)
        params, initial = vf.params, warm_start(vf, v0, grid)
    for done, table, settled in refine(robot_system(params), grid, target, initial, float(meta["horizon"]),
                                       float(meta["stage"])):
        info = {"grid": meta["grid"], "horizon": repr(done), "settled": str(settled),
                "wall_s": f"{time.perf_counter() - start:.2f}", "cpus": str(len(os.sched_getaffinity(0)))}
        atomic_write(workdir / RESULT, lambda tmp, t=table, i=info: save_file({"values": t}, tmp, metadata=i))


@dataclasses.dataclass
class Stage:
    """One refined table as the node reads it."""

    key: int
    grid: GridSpec
    values: np.ndarray
    horizon: float
    settled: bool
    wall_s: float
    cpus: int  # cores the child could run on (its affinity)


def child_cpus(requested: int, available: set[int]) -> set[int]:
    """The cores the refinement child may run on: ``requested`` of ``available`` (the highest-numbered);
    0 = all but one, so that the node's command path keeps a core the solver never takes; at least one."""
    ordered = sorted(available)
    n = len(ordered) - 1 if requested == 0 else requested
    return set(ordered[-max(1, min(n, len(ordered))):])


class BackgroundRefinement:
    """At most one refinement child process (nice 19, on ``child_cpus(cpus, ...)``) at a time, keyed by the
    caller's map version."""

    def __init__(self, cpus: int = 0) -> None:
        if cpus < 0:
            raise ValueError(f"cpus must be >= 0 (0 = all but one), got {cpus}")
        self.cpus = cpus
        self._proc: subprocess.Popen | None = None
        self._dir: Path | None = None
        self._key: int | None = None
        self._seen: tuple[int, int] | None = None  # (inode, mtime_ns) of the last result read (a new file a stage)
        self.error = ""

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def start(self, key: int, v0: np.ndarray, grid: GridSpec, model: str, horizon: float, stage: float) -> None:
        """Stop any previous run and refine ``v0`` on ``grid`` for ``horizon`` simulated s."""
        self.stop()
        remove_stale_workdirs()
        self._dir = Path(tempfile.mkdtemp(prefix=f"{WORKDIR_PREFIX}{os.getpid()}_"))
        write_request(self._dir / REQUEST, v0, grid, model, horizon, stage)
        self._log = open(self._dir / "log.txt", "w+")  # noqa: SIM115 - closed in stop()
        child = [sys.executable, "-m", "hjrno_ros.ros.brt_node.refinement_process", str(self._dir)]
        self._proc = subprocess.Popen(child, stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                      env={**os.environ, "XLA_PYTHON_CLIENT_PREALLOCATE": "false"})
        self._deprioritise(self._proc.pid)
        self._key, self._seen, self.error = key, None, ""

    def _deprioritise(self, pid: int) -> None:
        """Nice 19 and the cores of ``child_cpus``, set before the child starts any thread (all inherit them)."""
        try:
            os.setpriority(os.PRIO_PROCESS, pid, min(19, os.getpriority(os.PRIO_PROCESS, 0) + CHILD_NICE))
        except OSError:
            pass  # the child already finished, or the OS refuses: it runs at the node's priority
        try:
            os.sched_setaffinity(pid, child_cpus(self.cpus, os.sched_getaffinity(0)))
        except (OSError, AttributeError):  # finished, refused, or no affinity on this OS: the node's cores
            pass

    def poll(self) -> Stage | None:
        """The newest stage not read yet, or None; a failed child leaves ``error`` (one line)."""
        if self._dir is None:
            return None
        path = self._dir / RESULT
        stage = None
        try:
            st = path.stat()
            seen = (st.st_ino, st.st_mtime_ns)
        except FileNotFoundError:
            seen = None
        if seen is not None and seen != self._seen:
            self._seen = seen
            try:
                grid, values, meta = read_table(path)
                stage = Stage(self._key, grid, values, float(meta["horizon"]), meta["settled"] == "True",
                              float(meta["wall_s"]), int(meta["cpus"]))
            except (ValueError, KeyError) as err:
                self.error = f"refinement result refused: {err}"
        if self._proc is not None and self._proc.poll() not in (None, 0) and not self.error:
            self.error = f"refinement process exited with {self._proc.returncode}: {self._last_line()}"
        return stage

    def _last_line(self) -> str:
        self._log.seek(0)
        lines = [ln.strip() for ln in self._log.read().splitlines() if ln.strip()]
        return lines[-1] if lines else "no output"

    def stop(self) -> None:
        if self._proc is not None:
            if self._proc.poll() is None:
                self._proc.kill()
            self._proc.wait()
            self._log.close()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
        self._proc = self._dir = self._key = None


WORKDIR_PREFIX = "hjrno_refine_"  # + the node's pid + "_": a folder whose node died is removed on the next start


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_workdirs(root: str | Path | None = None) -> list[Path]:
    """Remove refinement folders left by nodes that no longer run (kill -9); the removed paths."""
    removed = []
    for path in Path(root or tempfile.gettempdir()).glob(f"{WORKDIR_PREFIX}*_*"):
        pid = path.name[len(WORKDIR_PREFIX):].split("_", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path)
    return removed


def _die_with_parent(workdir: Path, period: float = 0.5) -> None:
    """Child side: exit (removing the work folder) as soon as the node that started it is gone, even after
    kill -9 (the child is then re-parented)."""
    import threading

    parent = os.getppid()

    def watch() -> None:
        while True:
            time.sleep(period)
            if os.getppid() != parent:
                shutil.rmtree(workdir, ignore_errors=True)
                os._exit(1)

    threading.Thread(target=watch, name="parent_watch", daemon=True).start()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m hjrno_ros.ros.brt_node.refinement_process WORKDIR", file=sys.stderr)
        return 2
    try:
        _die_with_parent(Path(args[0]))
        run_request(Path(args[0]))
    except Exception as err:  # one line for the node's status
        print(f"refinement failed: {type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
