"""Calibration, held-out sets and ``hjrno simulate`` (studies/): real solves, real torch models, real files."""

import dataclasses
import json
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import copy_model

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.grids import GridSpec
from hjrno_ros.core.model_card import ModelCard
from hjrno_ros.core.safety_filter import MODES
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.operators.average import SymmetryAverage
from hjrno_ros.studies import calibration, evaluation, held_out
from hjrno_ros.studies.closed_loop import EpisodeSettings

HJRNO = [sys.executable, "-m", "hjrno_ros.cli"]
PARAMS = CarParams()




def test_conformal_rank_and_calibrated_margin_cover_fresh_draws():
    assert calibration.conformal_rank(100, 0.05, 0.5) == 96  # the textbook ceil((n + 1)(1 - alpha)) region
    with pytest.raises(ValueError, match="need at least 59"):
        calibration.conformal_rank(50, 0.05, 0.05)
    rng = np.random.default_rng(1)
    truth = [rng.uniform(-1, 1, (30, 30)) for _ in range(6)]
    pred = [t + rng.normal(0, 0.2, t.shape) for t in truth]
    cal = calibration.calibrate(pred, truth, alpha=0.05, beta=0.05, n=4000, seed=2, margin=0.05)
    assert 0.05 < cal.epsilon < 0.6 and cal.precision_bound >= cal.precision_estimate
    fresh_t = [rng.uniform(-1, 1, (30, 30)) for _ in range(6)]
    fresh_p = [t + rng.normal(0, 0.2, t.shape) for t in fresh_t]
    before, after = (calibration.error_rates(fresh_p, fresh_t, e) for e in (0.0, cal.epsilon))
    assert after["miss_rate"] <= 0.05 < before["miss_rate"]
    assert after["conservative_rate"] > before["conservative_rate"]


def test_calibrate_and_simulate_commands(trained, tmp_path):
    _, stem = trained
    local = copy_model(stem, tmp_path)
    weights_before = checkpoint.paths(local)[0].read_bytes()
    run = subprocess.run([*HJRNO, "calibrate", "--model", str(local), "--draws", "2000", "--alpha", "0.05"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    card = checkpoint.load_card(local)
    assert card["epsilon"] >= 0.1 and card["calibration"]["alpha"] == 0.05  # ε ≥ the default margin δ
    assert card["calibration"]["fresh_after"]["epsilon"] == card["epsilon"]
    assert checkpoint.paths(local)[0].read_bytes() == weights_before
    out = tmp_path / "sim"
    run = subprocess.run([*HJRNO, "simulate", "--model", f"tiny={local}", "--episodes", "6", "--duration", "4",
                          "--out", str(out), "--quiet"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    study = json.loads((out / "closed_loop.json").read_text())
    rows = study["rows"]
    assert {r["filter"]: r["collisions"] for r in rows} == {
        name: sum(study["collisions_by_world"][name].values()) for name in study["collisions_by_world"]}
    names = [r["filter"] for r in rows]
    assert names[:6] == ["none", "stop_zone", "ground_truth_least_restrictive", "ground_truth", "ground_truth_blend",
                         "ground_truth_qp"]
    assert any(n.startswith("tiny_qp (eps=") for n in names) and len(rows) == 11
    assert all(r["episodes"] == 6 for r in rows)
    assert (out / "closed_loop.png").stat().st_size > 10_000 and "Targets:" in (out / "closed_loop.md").read_text()


def test_calibrate_refuses_too_few_draws(trained):
    _, stem = trained
    run = subprocess.run([*HJRNO, "calibrate", "--model", str(stem), "--draws", "50", "--alpha", "0.01",
                          "--dry-run"], capture_output=True, text=True)
    assert run.returncode == 2 and "need at least" in run.stderr and len(run.stderr.strip().splitlines()) == 1


def test_calibrate_records_symmetry_averaging_in_the_card(trained, tmp_path):
    """--symmetry-average calibrates the averaged model and records it with ε, so every later load
    (evaluate, simulate, the node) predicts the way ε was measured; --no-symmetry-average undoes it."""
    _, stem = trained
    local = copy_model(stem, tmp_path)
    folders = checkpoint.load_card(local)["dataset"]["folders"]
    solved = held_out.load(folders, "all")
    plain, mean = (held_out.predict(local, solved, average) for average in (False, True))
    assert max(np.abs(p - m).max() for p, m in zip(plain, mean, strict=True)) > 1e-3
    for flag, averaged in (("--symmetry-average", True), ("--no-symmetry-average", False)):
        run = subprocess.run([*HJRNO, "calibrate", "--model", str(local), "--draws", "2000", "--alpha", "0.05", flag],
                             capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        card = checkpoint.load_card(local)
        assert card["symmetry_average"] is averaged and card["calibration"]["symmetry_average"] is averaged
        assert card["epsilon"] == calibration.calibrate_model(local, folders, 0.05, 0.05, 2000, write=False,
                                                              average=averaged)["epsilon"]
        model, _ = checkpoint.load_model(local)
        assert isinstance(model, SymmetryAverage) is averaged
        assert evaluation.evaluate(local)[0]["model"].endswith("D4-averaged)") is averaged


def test_calibrate_records_member_frames_in_the_card(trained, tmp_path):
    """--member-frames: each ensemble member predicts in its listed D4 frames; calibrated that way and
    recorded with ε, so later loads predict as ε was measured; 'none' clears; a malformed list is refused."""
    from hjrno_ros.learning import combine

    _, stem = trained
    ens = tmp_path / "ens"
    combine.combine([str(stem), str(stem)], ens, "test")  # identical members: frames alone differ
    folders = checkpoint.load_card(ens)["dataset"]["folders"]
    solved = held_out.load(folders, "all")
    plain, framed = (held_out.predict(ens, solved, frames=f) for f in ([], [[0], [4]]))
    assert max(np.abs(p - f).max() for p, f in zip(plain, framed, strict=True)) > 1e-3
    for flag, frames in (("0;4", [[0], [4]]), ("none", None)):
        run = subprocess.run([*HJRNO, "calibrate", "--model", str(ens), "--draws", "2000", "--alpha", "0.05",
                              "--member-frames", flag], capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        card = checkpoint.load_card(ens)
        assert card["member_frames"] == frames and card["calibration"]["member_frames"] == frames
        assert card["epsilon"] == calibration.calibrate_model(ens, folders, 0.05, 0.05, 2000, write=False,
                                                              frames=frames or [])["epsilon"]
        model, _ = checkpoint.load_model(ens)
        assert [getattr(m, "elements", None) for m in model.members] == ([(0,), (4,)] if frames else [None, None])
    run = subprocess.run([*HJRNO, "calibrate", "--model", str(ens), "--member-frames", "0;x", "--dry-run"],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "member frames" in run.stderr


def test_symmetry_averaging_refuses_a_non_square_window(trained):
    _, stem = trained
    model, card = checkpoint.load_typed(stem)
    g = card.grid
    wide = GridSpec(g.lo, (g.hi[0], 2 * g.hi[1], *g.hi[2:]), g.shape, g.periodic)
    card = dataclasses.replace(card, grid=wide, window=(wide.hi[0] - wide.lo[0], wide.hi[1] - wide.lo[1]))
    with pytest.raises(ValueError, match="square x-y window"):
        checkpoint.symmetry_averaged(model, card)


def test_held_out_halves_and_unconverged_worlds(ci_data, trained, tmp_path):
    import h5py

    _, stem = trained

    from hjrno_ros.studies import held_out

    full = tmp_path / "full"
    shutil.copytree(ci_data, full)
    model = copy_model(stem, tmp_path)
    card = checkpoint.load_card(model)
    checkpoint.update_card(model, {"dataset": {**card["dataset"], "test_folders": [str(full), str(ci_data)]}})

    calib, fresh = held_out.held_out_halves(5)
    assert calib == [0, 1, 2] and fresh == [3, 4]
    with pytest.raises(ValueError, match="at least 2"):
        held_out.held_out_halves(1)
    assert len(held_out.load([ci_data], "all")) == 2
    with h5py.File(ci_data / "test.h5", "r+") as f:  # flag one test sample as not converged
        flags = f["converged"][...]
        f["converged"][0] = False
    try:
        one_left = re.escape(f"{ci_data}: calibration needs at least 2 held-out scenarios")  # one converged left
        with pytest.raises(ValueError, match=one_left):
            held_out.load([ci_data], "fresh")
        assert [s.name for s in held_out.load([ci_data], "all")] == [held_out.load([ci_data], "all", True)[1].name]
        assert len(held_out.load([ci_data], "all", unconverged=True)) == 2
        assert not held_out.has_halves(ci_data) and held_out.has_halves(ci_data, unconverged=True)
        # calibrate/simulate without --data: the card's folder that cannot be halved is left out
        assert held_out.data_folders(None, str(model), False) == [str(full)]
        assert held_out.data_folders(None, str(model), True) == [str(full), str(ci_data)]
        assert held_out.data_folders(f"{ci_data}", str(model), False) == [str(ci_data)]  # chosen: kept, refused later
        with pytest.raises(ValueError):  # the calibration half lost its only scenario
            calibration.calibrate_model(stem, [ci_data], 0.05, 0.05, 2000, write=False)
        entry = calibration.calibrate_model(stem, [ci_data], 0.05, 0.05, 2000, write=False, unconverged=True)
        assert entry["unconverged_allowed"] and len(entry["calibration_scenarios"]) == 1
    finally:
        with h5py.File(ci_data / "test.h5", "r+") as f:
            f["converged"][...] = flags


def test_worlds_without_a_safe_start_are_skipped_with_a_note(ci_data, tmp_path):
    """A map too tight for the car (V∞ < start margin everywhere) cannot host an episode that any filter
    could win: the study leaves it out and says so; with no usable world at all it refuses."""
    import h5py

    from hjrno_ros.studies import filter_study

    folder = tmp_path / "tight"
    shutil.copytree(ci_data, folder)
    with h5py.File(folder / "test.h5", "r+") as f:
        f["value"][0] = -1.0
    names = [s.name for s in held_out.load([folder], "all")]
    settings = EpisodeSettings(duration=2.0)
    study = filter_study.run_study([str(folder)], {}, episodes=4, part="all", settings=settings,
                                   filters=["ground_truth"], progress=lambda m: None)
    assert study["worlds"] == names[1:] and list(study["skipped_worlds"]) == names[:1]
    assert "no safe start" in study["skipped_worlds"][names[0]]
    assert all(r["episodes"] == 4 for r in study["rows"])
    with h5py.File(folder / "test.h5", "r+") as f:
        f["value"][1] = -1.0
    with pytest.raises(ValueError, match="has a safe start"):
        filter_study.run_study([str(folder)], {}, episodes=4, part="all", settings=settings,
                               filters=["ground_truth"], progress=lambda m: None)


def test_simulate_adds_refined_filters(ci_data, trained, tmp_path):
    """``refine``: per model its table after the solver warm-started from it (brt_node's refine_horizon):
    never above the prediction or l, changed by the solve, and filtered beside the model in every mode."""
    from hjrno_ros.studies import filter_study

    _, stem = trained
    local = copy_model(stem, tmp_path)
    checkpoint.update_card(local, {"epsilon": 0.15})
    solved = held_out.load([ci_data], "all")
    predicted = held_out.predict(str(local), solved)
    refined = held_out.refine(solved, predicted, 1.0)
    for s, p, r in zip(solved, predicted, refined, strict=True):
        start = np.minimum(p, s.target)
        assert r.shape == s.grid.shape and np.all(r <= start + 1e-5) and float(np.abs(r - start).max()) > 1e-3
    study = filter_study.run_study([str(ci_data)], {"tiny": str(local)}, episodes=4, part="all",
                                   settings=EpisodeSettings(duration=2.0), refine=1.0, progress=lambda m: None)
    names = [r["filter"] for r in study["rows"]]
    eps = f"{study['truth_epsilon']:.3f}"
    assert [n for n in names if "refined" in n] == [
        *(f"tiny_refined1s{'' if mode == 'switch' else '_' + mode} (eps=0.150)" for mode in MODES),
        f"tiny_refined1s (eps={eps}, no model margin)"]
    assert len(names) == 2 + 3 * len(MODES) + 2 and study["refine_s"] == 1.0
    assert all(r["episodes"] == 4 for r in study["rows"])


def test_calibrate_refine_writes_a_margin_for_refined_tables(trained, tmp_path):
    """``calibrate --refine T`` calibrates the tables the solver refined for T simulated s: it writes
    refine_epsilon (≥ δ) for stages ≥ T and leaves the operator's ε as it was; simulate --refine uses it."""
    from hjrno_ros.studies import filter_study

    _, stem = trained
    local = copy_model(stem, tmp_path)
    checkpoint.update_card(local, {"epsilon": 0.15})
    run = subprocess.run([*HJRNO, "calibrate", "--model", str(local), "--draws", "2000", "--alpha", "0.05",
                          "--refine", "1"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    card = checkpoint.load_card(local)
    eps, entry = card["refine_epsilon"], card["refine_calibration"]
    assert card["epsilon"] == 0.15 and "calibration" not in card and eps >= 0.1 and entry["horizon_s"] == 1.0
    assert entry["fresh_after"]["epsilon"] == eps and entry["alpha"] == 0.05
    folders = card["dataset"]["folders"]
    solved = held_out.load(folders, "calibration")
    refined = held_out.refine(solved, held_out.predict(local, solved), 1.0)
    assert eps == calibration.calibrate(refined, [s.value for s in solved], 0.05, 0.05, 2000, 0, 0.1).epsilon
    typed = ModelCard.load(local)
    assert (typed.refine_epsilon, typed.refine_horizon) == (eps, 1.0)
    assert typed.refined_margin(2.0) == eps and typed.refined_margin(0.5) == 0.15 == typed.margin()
    for horizon, shown in ((1.0, eps), (0.5, 0.15)):
        study = filter_study.run_study(folders, {"tiny": str(local)}, episodes=2,
                                       settings=EpisodeSettings(duration=1.0), refine=horizon,
                                       filters=["tiny_refined"], progress=lambda m: None)
        assert f"tiny_refined{horizon:g}s (eps={shown:.3f})" in [r["filter"] for r in study["rows"]], study["rows"]
    run = subprocess.run([*HJRNO, "calibrate", "--model", str(local), "--draws", "2000", "--alpha", "0.05",
                          "--refine", "1", "--symmetry-average"], capture_output=True, text=True)
    assert run.returncode == 2 and "card's" in run.stderr and len(run.stderr.strip().splitlines()) == 1
    assert checkpoint.load_card(local) == card
