"""The closed-loop comparison of safety filters behind ``hjrno simulate`` (no ROS).

Filters: ``none``; ``stop_zone`` (Nav2 collision-monitor style, :mod:`stop_zone`); the ground-truth
HJ filter (V∞ table from the solver, margin δ); learned HJ filters (a model's V table on the same
window, with the model card's calibrated ε, and with δ alone: "no model margin").  The ground-truth
and calibrated filters run in every mode (switch, least_restrictive, blend, qp); least_restrictive's braking
bound reads the world's target l − r on the grid, as brt_node reads its map.  Every filter sees the same
worlds, starts, goals and disturbance sequences.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.least_restrictive import certificate, filter_least_restrictive
from hjrno_ros.core.model_card import ModelCard
from hjrno_ros.core.safety_filter import MODES, FilterSettings, filter_batch, sampling_margin
from hjrno_ros.core.similarity import Dimensionless, Scaling
from hjrno_ros.core.stop_zone import StopZoneSettings, stop_zone_filter
from hjrno_ros.core.tables import markdown_table
from hjrno_ros.core.value_table import ReversingTable, ValueTable
from hjrno_ros.studies import closed_loop, held_out
from hjrno_ros.studies.calibration import DEFAULT_MARGIN
from hjrno_ros.studies.closed_loop import EpisodeSettings, World

TRUTH = "ground_truth"
# Robots a study can drive besides the worlds' own car: (κ_max 1/m, v_max m/s); a_max takes each world's
# a_max/(κ_max·v_max²), so the solved ground truth holds exactly at the robot's size (core/similarity.py).
ROBOTS = {"turtlebot3": (2.84 / 0.22, 0.22)}


@dataclasses.dataclass(frozen=True)
class FilterChoice:
    """One row of the table: ``kind`` none | stop_zone | hj; ``source`` "ground_truth" or a model label."""

    name: str
    kind: str
    source: str = ""
    mode: str = "switch"
    epsilon: float = 0.0


def default_filters(models: dict[str, float | None], truth_epsilon: float) -> list[FilterChoice]:
    """none, stop_zone, ground truth (switch, blend, qp with ε = δ) and per model (label -> its card's calibrated
    ε, None if uncalibrated): that ε (switch, blend, qp) and ε = δ alone ("no model margin": what calibration
    adds, measured)."""
    rows = [FilterChoice("none", "none"), FilterChoice("stop_zone", "stop_zone")]
    rows += [FilterChoice(_name(TRUTH, mode), "hj", TRUTH, mode, truth_epsilon) for mode in MODES]
    for label, eps in models.items():
        if eps is not None:
            rows += [FilterChoice(f"{_name(label, mode)} (eps={eps:.3f})", "hj", label, mode, float(eps))
                     for mode in MODES]
        rows.append(FilterChoice(f"{label} (eps={truth_epsilon:.3f}, no model margin)", "hj", label, "switch",
                                 truth_epsilon))
    return rows


def _name(source: str, mode: str) -> str:
    return source if mode == "switch" else f"{source}_{mode}"  # "switch" keeps the names of the first studies


def refined_label(label: str, horizon: float) -> str:
    return f"{label}_refined{horizon:g}s"


def robot_world(solved: held_out.Solved, predicted: dict[str, np.ndarray], robot: str | None
                ) -> tuple[World, dict[str, ValueTable | ReversingTable]]:
    """A held-out world and its tables (ground truth + models) as seen by ``robot`` (None: the world's car).  A
    product world solved for forward speeds gets a reversing robot (v_min = −v_max) and its tables answer
    reversing states by symmetry (:class:`ReversingTable`)."""
    p = solved.scenario.dynamics_params()
    reverse = p.d0 == 0 and p.v_min == 0
    if reverse:
        p = dataclasses.replace(p, v_min=-p.v_max)
    scaling = Scaling(1.0, 1.0)
    if robot is not None:
        if robot not in ROBOTS:
            raise ValueError(f"unknown robot {robot!r}; known: {', '.join(ROBOTS)}")
        kappa, v_max = ROBOTS[robot]
        target = CarParams(a_max=Dimensionless.of(p).accel_ratio * kappa * v_max ** 2, kappa_max=kappa,
                           d0=p.d0 / p.v_max * v_max, v_min=p.v_min / p.v_max * v_max, v_max=v_max,
                           tracking_error=p.tracking_error)
        mine, theirs = Scaling.of(p), Scaling.of(target)
        scaling, p = Scaling(theirs.length / mine.length, theirs.time / mine.time), target

    def table(values: np.ndarray) -> ValueTable | ReversingTable:
        t = ValueTable(scaling.grid_to_robot(solved.grid), values * scaling.length)
        return ReversingTable(t) if reverse else t

    grid = scaling.grid_to_robot(solved.grid)
    target = RegularGridInterpolator((grid.axis(0), grid.axis(1)), solved.target[:, :, 0, 0] * scaling.length,
                                     bounds_error=False, fill_value=None)
    world = World(solved.name, solved.scenario.shapes, table(solved.value), p, scale=scaling.length,
                  grid_clearance=target)
    return world, {TRUTH: world.truth, **{label: table(v) for label, v in predicted.items()}}


def node_inflated(solved: held_out.Solved) -> held_out.Solved:
    """The world as brt_node sees it: obstacles grown by the grid's h/√2 (its default ``inflation_radius``), so
    walls thinner than a cell cannot hide between nodes.  Where the dataset was solved without it this is exact:
    V∞ of l − r is V∞ of l minus r (the payoff is the least l along a path)."""
    r = max(0.0, solved.grid.half_cell_diagonal - solved.inflation)
    return dataclasses.replace(solved, target=solved.target - np.float32(r), value=solved.value - np.float32(r),
                               inflation=solved.inflation + r)


def make_filter(choice: FilterChoice, world: World, tables: dict[str, ValueTable],
                stop: StopZoneSettings, dt: float, decay_rate: float) -> closed_loop.Filter | None:
    """The filter of one table row; margins (ε, stop-zone distances) in the world's units scale with it."""
    if choice.kind == "none":
        return None
    if choice.kind == "stop_zone":
        stop = dataclasses.replace(stop, stop_distance=stop.stop_distance * world.scale,
                                   footprint_margin=stop.footprint_margin * world.scale)
        return lambda s, nominal: stop_zone_filter(stop, world.clearance, s, nominal)
    table = tables[choice.source]
    ahead = choice.mode == "least_restrictive"  # looks one period ahead: no sampling margin (as brt_node)
    eps = choice.epsilon * world.scale + (0.0 if ahead else sampling_margin(world.params, dt))
    settings = FilterSettings(epsilon=eps, mode=choice.mode, dt=dt, decay_rate=decay_rate,
                              blend_width=FilterSettings.blend_width * world.scale)
    if ahead:
        cert = certificate(world.params, world.grid_clearance, table, eps)
        return lambda s, nominal: filter_least_restrictive(world.params, settings, cert, s, nominal)[:2]
    return lambda s, nominal: filter_batch(world.params, settings, s, *table.value_and_gradient(s), nominal)


def run_study(folders: list[str], models: dict[str, str], episodes: int = 500, seed: int = 0,
              truth_epsilon: float = DEFAULT_MARGIN, part: str = "fresh", settings: EpisodeSettings = EpisodeSettings(),
              stop: StopZoneSettings = StopZoneSettings(), filters: list[str] | None = None,
              progress=print, unconverged: bool = False, decay_rate: float = FilterSettings.decay_rate,
              inflation_at: str = "input", refine: float = 0.0, robot: str | None = None,
              worlds: int | None = None) -> dict:
    """Run every filter over ≥ ``episodes`` episodes spread evenly over the held-out worlds
    (``inflation_at``: how the learned maps meet the datasets' inflation, ``held_out.INFLATION_AT``).
    ``refine`` > 0 adds per model a filter on its table refined by ``refine`` simulated s of the solver
    warm-started from it (what brt_node's ``refine_horizon`` does), with the card's ε for that table
    (:meth:`ModelCard.refined_margin`).  ``robot``: drive a :data:`ROBOTS` robot instead of the worlds' car (the
    worlds, margins and episode lengths at its size); ``worlds``: only the first this many held-out worlds."""
    solved = [node_inflated(s) for s in held_out.load(folders, part, unconverged)][:worlds]
    if not solved:
        raise ValueError(f"no converged held-out scenarios in {folders} ({part})")
    usable = [closed_loop.has_safe_states(s.grid, s.value, settings) for s in solved]
    skipped = {s.name: f"no state with V_gt >= {settings.start_margin} m: no safe start exists"
               for s, ok in zip(solved, usable, strict=True) if not ok}
    for name, why in skipped.items():
        progress(f"skipping world {name}: {why}")
    solved = [s for s, ok in zip(solved, usable, strict=True) if ok]
    if not solved:
        raise ValueError(f"no held-out world in {folders} ({part}) has a safe start")
    cards = {label: ModelCard.load(stem) for label, stem in models.items()}
    epsilons = {label: card.epsilon for label, card in cards.items()}  # calibrated only: no row for an uncalibrated ε
    if refine > 0:
        epsilons.update({refined_label(label, refine): card.refined_margin(refine) for label, card in cards.items()})
    choices = default_filters(epsilons, truth_epsilon)
    if filters:
        choices = [c for c in choices if any(c.name.startswith(f) for f in filters)]
        if not choices:
            raise ValueError(f"--filters {filters} match none of the filters")
    start = time.perf_counter()
    predicted = {label: held_out.predict(stem, solved, inflation_at=inflation_at) for label, stem in models.items()}
    infer_s = (time.perf_counter() - start) / max(len(solved), 1)
    refine_s = 0.0
    if refine > 0:
        start = time.perf_counter()
        predicted.update({refined_label(label, refine): held_out.refine(solved, p, refine)
                          for label, p in list(predicted.items())})
        refine_s = (time.perf_counter() - start) / max(len(solved), 1)
        progress(f"refined {len(models)} model(s) for {refine:g} simulated s: {refine_s:.1f} s per world")
    per_world = -(-episodes // len(solved))
    results: dict[str, list[dict]] = {c.name: [] for c in choices}
    traces: dict[str, tuple] = {}
    for w, s in enumerate(solved):
        world, tables = robot_world(s, {label: p[w] for label, p in predicted.items()}, robot)
        world_settings = settings.scaled(world.scale)
        eps = closed_loop.draw_episodes(world, per_world, world_settings, seed=seed * 100003 + w,
                                        first=w * per_world)
        for c in choices:
            filt = make_filter(c, world, tables, stop, settings.dt, decay_rate)
            r = closed_loop.run_episodes(world, eps, filt, world_settings, trace=w == 0)
            if w == 0:
                traces[c.name] = r.pop("trace")
            results[c.name].append(r)
        progress(f"world {w + 1}/{len(solved)} {s.name}: {per_world} episodes x {len(choices)} filters, "
                 f"{time.perf_counter() - start:.0f} s")
    rows = [{"filter": c.name, "epsilon": c.epsilon if c.kind == "hj" else None, "mode": c.mode if c.kind == "hj"
             else c.kind, **closed_loop.summarize(results[c.name])} for c in choices]
    collided = {c.name: [int((r["outcome"] == "collision").sum()) for r in results[c.name]] for c in choices}
    where = {name: {s.name: n for s, n in zip(solved, counts, strict=True) if n} for name, counts in collided.items()}
    return {"rows": rows, "worlds": [s.name for s in solved], "skipped_worlds": skipped,
            "episodes_per_world": per_world,
            "map_inference_ms": 1e3 * infer_s, "refine_s": refine, "refine_wall_s_per_world": refine_s,
            "settings": dataclasses.asdict(settings),
            "stop_zone": dataclasses.asdict(stop), "models": {k: str(v) for k, v in models.items()},
            "seed": seed, "truth_epsilon": truth_epsilon, "qp_decay_rate": decay_rate,
            "unconverged_worlds_allowed": unconverged, "inflation_at": inflation_at,
            "collisions_by_world": where, "first_world": solved[0], "traces": traces,
            "robot": robot or "the worlds car", "last_world_robot": dataclasses.asdict(world.params)}


COLUMNS = [("filter", "filter", "{}"), ("episodes", "episodes", "{}"), ("collisions", "collisions", "{}"),
           ("collisions_worst_d", "of them worst-case d", "{}"), ("intervention_rate", "intervention rate", "{:.3f}"),
           ("raised_speed", "|v| above nominal", "{}"),
           ("goals_reached", "goals reached", "{:.2f}"), ("distance_m", "distance m", "{:.2f}"),
           ("min_clearance_m", "min clearance m", "{:.3f}"), ("mean_min_clearance_m", "mean min clearance m",
                                                              "{:.2f}"),
           ("jerk_rms", "jerk m/s³ (rms)", "{:.2f}"), ("angacc_rms", "ang. acc. rad/s² (rms)", "{:.2f}"),
           ("filter_us", "filter µs/decision", "{:.0f}")]


def write_tables(study: dict, out: Path, command: str) -> tuple[Path, Path, Path]:
    """closed_loop.md (+ targets checked), closed_loop.csv and closed_loop.json under ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    rows = study["rows"]
    with (out / "closed_loop.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    lines = markdown_table([c[1] for c in COLUMNS], ([fmt.format(r[k]) for k, _, fmt in COLUMNS] for r in rows))
    md = [f"# Closed-loop safety filters ({time.strftime('%Y-%m-%d')})", "", f"Command: `{command}`", "",
          f"{len(study['worlds'])} held-out worlds ({', '.join(sorted({w.split('/')[0] for w in study['worlds']}))}), "
          f"{study['episodes_per_world']} episodes each; duration {study['settings']['duration']} s, "
          f"dt {study['settings']['dt']} s; controllers alternate goal / straight"
          + (" (1 in 10 reverses, 1 in 10 spins in place)" if study['settings'].get('careless') else "")
          + f", disturbance alternates random / worst-case (ground-truth gradient), ‖d‖ ≤ δ·|v| + d₀; robot: "
          f"{study.get('robot', 'the worlds car')}.  Learned maps: "
          f"{study['map_inference_ms']:.0f} ms per world for the whole (v, θ) table (all models)"
          + ("; they read l and the datasets' inflation comes off their output (--inflation-at output)."
             if study.get("inflation_at") == "output" else ".")
          + (f"  Refined (`--refine {study['refine_s']:g}`): each model's table after {study['refine_s']:g} "
             f"simulated s of the solver warm-started from it, {study['refine_wall_s_per_world']:.1f} s per world."
             if study.get("refine_s") else ""),
          *[f"Skipped {w}: {why}." for w, why in study.get("skipped_worlds", {}).items()], "",
          *lines, "", *check_targets(rows), "", "Collisions by world (HJ filters):",
          *[f"- {name}: {', '.join(f'{w} ({n})' for w, n in worlds.items())}"
            for name, worlds in study["collisions_by_world"].items() if worlds and name not in ("none", "stop_zone")]]
    (out / "closed_loop.md").write_text("\n".join(md) + "\n")
    meta = {k: v for k, v in study.items() if k not in ("traces", "first_world")}
    (out / "closed_loop.json").write_text(json.dumps({**meta, "command": command}, indent=1, default=str))
    return out / "closed_loop.md", out / "closed_loop.csv", out / "closed_loop.json"


def check_targets(rows: list[dict]) -> list[str]:
    """The issue's targets, checked against the table: each learned filter with its calibrated ε has 0
    collisions in ≥ 500 episodes and intervenes ≤ 1.2× as often as the ground-truth filter of its mode."""
    by = {r["filter"]: r for r in rows}
    lines = ["Targets:"]
    for r in rows:
        name = r["filter"]
        if r["mode"] not in MODES or name.startswith(TRUTH) or "no model margin" in name:
            continue
        ok = r["collisions"] == 0 and r["episodes"] >= 500
        lines.append(f"- {name}: {r['collisions']} collisions in {r['episodes']} episodes "
                     f"({'met' if ok else 'MISSED'}: 0 in ≥ 500)")
        truth = by.get(_name(TRUTH, r["mode"]))
        if truth:
            ratio = r["intervention_rate"] / max(truth["intervention_rate"], 1e-12)
            lines.append(f"- {name}: intervention rate {ratio:.2f}× that of {truth['filter']} "
                         f"({'met' if ratio <= 1.2 else 'MISSED'}: ≤ 1.2×)")
    for name in ("stop_zone", "none"):
        if name in by:
            lines.append(f"- {name}: {by[name]['collisions']} collisions, intervention rate "
                         f"{by[name]['intervention_rate']:.3f}, goals reached {by[name]['goals_reached']:.2f}")
    return lines
