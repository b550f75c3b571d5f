"""The operator's value over a whole static map, refined by the HJ solver warm-started from it.

The operator predicts V on a robot-centred window in milliseconds, but indoors its turn (the sign of
∂V/∂θ near V = 0) disagrees with the truth's on ~12 % of states, and that turn is what makes its filter
collide.  ``solve(..., initial=W)`` from the operator's prediction W corrects it in a fraction
of a cold solve's time (docs/results.md, warm-start study, 16 indoor rooms: sign agreement 0.875 → 0.919 after
16 simulated s, 8.7 s of wall time per 10 m room here against ~75 s cold; 0 and 0 collisions in 2002
closed-loop episodes against the operator's 6 and 13).  For a map that does not change, that is worth
doing once, in the background, while the operator's windows keep the filter running.

* :func:`map_grid`: the (x, y, v, θ) grid over the map at the model's spacings.
* :func:`warm_start`: the operator's prediction on that grid, stitched from windows: each x-y node takes
  the window whose centre is nearest to it (windows overlap by half), at every (v, θ) node.
* :func:`refine`: the warm-started solve in stages of simulated time, each stage's table yielded.
* :func:`main`: the child process that :class:`BackgroundRefinement` (the node's) starts: it reads a
  request file and writes each stage's table over the same output file, atomically.
Axis order everywhere: V[ix, iy, iv, iθ] (docs/design.md, "Conventions").
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from hjrno_ros.core.atomic import atomic_write
from hjrno_ros.core.grids import GridSpec

SOLVER = {"accuracy": "high", "tolerance": 3e-3, "criterion": "band"}  # the indoor datasets' settings
REQUEST, RESULT = "request.safetensors", "value.safetensors"
CHILD_NICE = 19  # the solver process yields every core to the node
MAX_STATES = 4_000_000  # (x, y, v, θ) nodes: ~170 × 170 x-y nodes of the default model (a 54 m square map)


def map_grid(model_grid: GridSpec, lo: tuple[float, float], hi: tuple[float, float]) -> GridSpec:
    """The model grid's (v, θ) axes and x-y spacing over the box [lo, hi] (grown to whole steps, centred,
    at least one window): nodes of windows placed every half window coincide with this grid's nodes."""
    h = model_grid.spacings[:2]
    n = [max(model_grid.shape[i], math.ceil((hi[i] - lo[i]) / h[i] - 1e-4) + 1) for i in range(2)]  # float32 maps
    c = [(lo[i] + hi[i]) / 2 for i in range(2)]
    xy_lo = [c[i] - (n[i] - 1) * h[i] / 2 for i in range(2)]
    xy_hi = [c[i] + (n[i] - 1) * h[i] / 2 for i in range(2)]
    return GridSpec((*xy_lo, *model_grid.lo[2:]), (*xy_hi, *model_grid.hi[2:]), (*n, *model_grid.shape[2:]),
                    model_grid.periodic)


def window_starts(n: int, w: int) -> list[int]:
    """First node of each window of ``w`` nodes along an axis of ``n`` (every w//2, the last flush)."""
    return sorted({*range(0, n - w + 1, max(1, w // 2)), n - w})


def owners(n: int, w: int, starts: list[int]) -> np.ndarray:
    """Per node, the index into ``starts`` of the window whose centre is nearest."""
    centres = np.asarray(starts) + (w - 1) / 2
    return np.argmin(np.abs(np.arange(n)[:, None] - centres[None]), axis=1)


def warm_start(vf, v0: np.ndarray, grid: GridSpec) -> np.ndarray:
    """The operator's V on ``grid`` (Nx, Ny, Nv, Nθ) from V0 (Nx, Ny) on its x-y nodes."""
    if v0.shape != grid.shape[:2]:
        raise ValueError(f"V0 shape {v0.shape} does not match the grid's x-y shape {grid.shape[:2]}")
    wx, wy = vf.shape
    vv, tt = np.meshgrid(grid.axis(2), grid.axis(3), indexing="ij")
    out = np.empty(grid.shape, np.float32)
    sx, sy = window_starts(grid.shape[0], wx), window_starts(grid.shape[1], wy)
    ox, oy = owners(grid.shape[0], wx, sx), owners(grid.shape[1], wy, sy)
    for a, i in enumerate(sx):
        for b, j in enumerate(sy):
            slices = vf.predict(v0[i:i + wx, j:j + wy], vv.ravel(), tt.ravel())  # (Nv·Nθ, wx, wy)
            table = np.moveaxis(slices.reshape(*vv.shape, wx, wy), (0, 1), (2, 3))
            mx, my = np.flatnonzero(ox == a), np.flatnonzero(oy == b)
            out[np.ix_(mx, my)] = table[np.ix_(mx - i, my - j)]
    return out


def broadcast_target(v0: np.ndarray, grid: GridSpec) -> np.ndarray:
    """l(x, y, v, θ) = V0(x, y): the target of a map whose obstacles do not depend on the speed."""
    return np.ascontiguousarray(np.broadcast_to(v0[:, :, None, None], grid.shape), np.float32)


def refine(dynamics, grid: GridSpec, target: np.ndarray, initial: np.ndarray, horizon: float, stage: float
           ) -> Iterator[tuple[float, np.ndarray, bool]]:
    """(simulated s so far, table, settled) after each ``stage`` s of the tube of ``target`` l from
    min(initial, l); stops at ``horizon`` or when the solver's tolerance says it settled."""
    from hjrno_ros.truth.solver import solve  # JAX: only where a solve runs

    if not (horizon > 0 and stage > 0):
        raise ValueError(f"need horizon > 0 and stage > 0, got {horizon}, {stage}")
    done, current = 0.0, initial
    while done < horizon - 1e-9:
        length = min(stage, horizon - done)
        current, report = solve(dynamics, grid, target, initial=current, chunk=min(1.0, length),
                                max_horizon=length, **SOLVER)
        done += report.horizon
        yield done, current, report.converged
        if report.converged:
            return


# ---------------------------------------------------------------------------------------------
# The background process.

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
        self._proc = subprocess.Popen([sys.executable, "-m", "hjrno_ros.truth.refinement", str(self._dir)],
                                      stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
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
        print("usage: python -m hjrno_ros.truth.refinement WORKDIR", file=sys.stderr)
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
