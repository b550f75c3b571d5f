"""Figures of value functions: x-y slices of the BRT {V ≤ 0} with the obstacle {l ≤ 0} drawn."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hjrno_ros.core.grids import GridSpec  # noqa: E402

LEGEND = "(grey: obstacle l≤0, red: BRT V∞≤0)"


def _slice_indices(n: int, count: int) -> list[int]:
    return sorted(set(np.linspace(0, n - 1, count).round().astype(int).tolist()))


def _panel(ax, grid: GridSpec, target: np.ndarray, value: np.ndarray, i: int, j: int | None) -> None:
    """One x-y slice at third-axis index i (v, or ψ for Air3D) and θ index j (car only)."""
    x, y = grid.axis(0), grid.axis(1)
    idx = (slice(None), slice(None), i) + (() if j is None else (j,))
    v, l_ = value[idx].T, target[idx].T
    if v.min() < 0:
        ax.contourf(x, y, v, levels=[v.min() - 1, 0.0], colors=["#f4a6a6"])
        ax.contour(x, y, v, levels=[0.0], colors=["#b00000"], linewidths=1.2)
    if l_.min() < 0:
        ax.contourf(x, y, l_, levels=[l_.min() - 1, 0.0], colors=["#404040"])
    label = f"{'v' if grid.ndim == 4 else 'ψ'}={grid.axis(2)[i]:.2f}"
    if j is not None:
        label += f", θ={grid.axis(3)[j]:.2f}"
    ax.set_title(label, fontsize=9)
    ax.set_xlim(x[0], x[-1])
    ax.set_ylim(y[0], y[-1])
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)


def save_figure(fig, path: str | Path, title: str) -> Path:
    """Title, tighten, write the PNG (folders made as needed) and free the figure."""
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _columns(grid: GridSpec) -> list[tuple[int, int | None]]:
    """(third-axis index, θ index) of the slices shown per sample."""
    if grid.ndim == 3:
        return [(i, None) for i in _slice_indices(grid.shape[2], 4)]
    mid_v, top_v = grid.shape[2] // 2, grid.shape[2] - 1
    quarter = grid.shape[3] // 4
    return [(0, 0), (mid_v, 0), (top_v, 0), (top_v, quarter)]


def brt_slices(path: str | Path, grid: GridSpec, target: np.ndarray, value: np.ndarray, title: str = "") -> Path:
    """PNG of x-y slices: rows over the third axis (v, or ψ for Air3D), columns over θ (car only)."""
    rows = _slice_indices(grid.shape[2], 3)
    cols = list(range(0, grid.shape[3], max(1, grid.shape[3] // 4)))[:4] if grid.ndim == 4 else [None]
    fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.2 * len(cols), 3.0 * len(rows)), squeeze=False)
    for r, i in enumerate(rows):
        for c, j in enumerate(cols):
            _panel(axes[r][c], grid, target, value, i, j)
    return save_figure(fig, path, f"{title}  {LEGEND}")


def dataset_samples(path: str | Path, split, count: int = 4) -> Path:
    """PNG of the first ``count`` samples of a loaded split: one row each, a few (v, θ) slices."""
    count = max(1, min(count, len(split.target)))
    cols = _columns(split.grid)
    fig, axes = plt.subplots(count, len(cols), figsize=(3.0 * len(cols), 2.9 * count), squeeze=False)
    for r in range(count):
        for c, (i, j) in enumerate(cols):
            _panel(axes[r][c], split.grid, split.target[r], split.value[r], i, j)
        axes[r][0].set_ylabel(f"seed {split.scenarios[r].seed}", fontsize=9)
    return save_figure(fig, path, f"{split.config.name} ({split.attrs['split']})  {LEGEND}")


OUTCOME_COLORS = {"collision": "#d00000", "goal": "#2a9d2a", "exited": "#1f5fbf", "timeout": "#9a6fb0"}


def closed_loop_figure(path: str | Path, solved, traces: dict, rows: list[dict]) -> Path:
    """One panel per filter: the first world's obstacles and its episodes' paths coloured by outcome
    (red collision, green goal, blue left the window, purple time out); last panel: collisions and
    intervention rates of all filters."""
    names = list(traces)
    cols = 4
    n_rows = -(-(len(names) + 1) // cols)
    fig, axes = plt.subplots(n_rows, cols, figsize=(3.3 * cols, 3.3 * n_rows), squeeze=False)
    grid = solved.grid
    x, y = grid.axis(0), grid.axis(1)
    l_xy = solved.target[:, :, 0, 0].T
    for ax, name in zip(axes.flat, names, strict=False):
        states, outcome, goals = traces[name]
        ax.contourf(x, y, l_xy, levels=[l_xy.min() - 1, 0.0], colors=["#404040"])
        for e in range(states.shape[1]):
            ax.plot(states[:, e, 0], states[:, e, 1], color=OUTCOME_COLORS[outcome[e]], lw=0.9)
            ax.plot(*states[0, e, :2], "k.", ms=3)
        ax.plot(goals[:, 0], goals[:, 1], "x", color="#2a9d2a", ms=4)
        ax.set_title(name, fontsize=8)
        ax.set_xlim(x[0], x[-1])
        ax.set_ylim(y[0], y[-1])
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
    ax = axes.flat[len(names)]
    pos = np.arange(len(rows))
    ax.barh(pos - 0.2, [r["collision_rate"] for r in rows], 0.4, color="#d00000", label="collision rate")
    ax.barh(pos + 0.2, [r["intervention_rate"] for r in rows], 0.4, color="#1f5fbf", label="intervention rate")
    ax.set_yticks(pos, [r["filter"] for r in rows], fontsize=6)
    ax.invert_yaxis()
    ax.legend(fontsize=6)
    ax.tick_params(labelsize=6)
    for ax in list(axes.flat)[len(names) + 1:]:
        ax.axis("off")
    return save_figure(fig, path, f"closed loop on {solved.name} (all worlds in the bar chart)")


def demo_animation(out: Path, occupancy: np.ndarray, resolution: float, log, goals: np.ndarray,
                   gif: bool = True, view: float = 7.0, frame_s: float = 0.5, footprint: float = 0.1) -> list[Path]:
    """demo.png (whole run) and demo.gif (one frame per ``frame_s``): obstacles, the node's latest BRT
    slice (red: V ≤ 0 at the robot's speed and heading), the path so far (orange where the filter
    intervened), the robot as a disk of radius ``footprint`` (m, to the map's scale) and its goals; the view
    is [-view, view]²."""
    from matplotlib import animation

    size = occupancy.shape[0] * resolution
    extent = (-size / 2, size / 2, -size / 2, size / 2)
    states = np.array([s[:6] for s in log.states], float) if log.states else np.zeros((0, 6))
    fig, ax = plt.subplots(figsize=(5.2, 5.2))
    ax.imshow(occupancy.T > 50, origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=1.6)
    brt = ax.imshow(np.zeros((2, 2)), origin="lower", extent=(0, 1, 0, 1), cmap="Reds", vmin=0, vmax=2.5, alpha=0.5)
    ax.plot(goals[:, 0], goals[:, 1], "x", color="#2a9d2a", ms=7)
    path, = ax.plot([], [], color="#1f5fbf", lw=1.2)
    over = ax.scatter([], [], s=4, color="#ff8800")
    robot = ax.add_patch(plt.Circle((0.0, 0.0), footprint, color="k", alpha=0.8, visible=False))
    heading, = ax.plot([], [], "-", color="k", lw=1.5)
    ax.set_xlim(-view, view)
    ax.set_ylim(-view, view)
    ax.set_aspect("equal")
    title = ax.set_title("")

    def draw(t: float) -> None:
        k = np.searchsorted(states[:, 0], t, side="right") if len(states) else 0
        seen = [g for g in log.grids if g[0] <= t]
        if seen:
            _, origin, res, mask = seen[-1]
            brt.set_data(np.ma.masked_where(~mask.T, mask.T.astype(float)))
            brt.set_extent((origin[0], origin[0] + mask.shape[0] * res, origin[1], origin[1] + mask.shape[1] * res))
        if k:
            s = states[:k]
            path.set_data(s[:, 1], s[:, 2])
            over.set_offsets(s[s[:, 5] > 0][:, 1:3] if (s[:, 5] > 0).any() else np.zeros((0, 2)))
            x, y, _, th = s[-1, 1:5]
            robot.set(center=(x, y), visible=True)
            heading.set_data([x, x + 2.4 * footprint * np.cos(th)], [y, y + 2.4 * footprint * np.sin(th)])
        crash = log.collided_at is not None and t >= log.collided_at
        title.set_text(f"t = {t:4.1f} s" + ("  COLLISION" if crash else "") + "  (red: BRT slice, orange: filtered)")

    end = states[-1, 0] if len(states) else 0.0
    out = Path(out)
    written = []
    if gif and len(states):
        times = np.arange(0.0, end + frame_s, frame_s)
        anim = animation.FuncAnimation(fig, draw, frames=times, interval=1000 * frame_s)
        anim.save(out / "demo.gif", writer=animation.PillowWriter(fps=int(round(2 / frame_s))), dpi=70)
        written.append(out / "demo.gif")
    draw(end)
    fig.savefig(out / "demo.png", dpi=90)
    plt.close(fig)
    return [out / "demo.png", *written]
