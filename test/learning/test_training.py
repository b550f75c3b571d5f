"""Training, checkpoints and evaluation on the tiny `ci` dataset: real solves, real torch, real files."""

import dataclasses
import json
import pickle

import numpy as np
import pytest
import torch
from conftest import SMALL, copy_model
from scipy.interpolate import RegularGridInterpolator

from hjrno_ros.core.geometry import Polygon
from hjrno_ros.core.grids import car_grid
from hjrno_ros.datasets import dataset
from hjrno_ros.learning import checkpoint
from hjrno_ros.learning.operators.average import SymmetryAverage
from hjrno_ros.learning.slices import (
    SliceSet,
    SliceUnion,
    angle_difference_l2,
    level_set_weight,
    relative_l2,
    spec_for,
    symmetry,
)
from hjrno_ros.learning.training import TrainConfig, TrainingDiverged, train
from hjrno_ros.learning.value_function import LearnedValueFunction
from hjrno_ros.studies import evaluation
from hjrno_ros.truth.solver import solve
from hjrno_ros.truth.systems import DynamicDubinsCar


def test_inputs_follow_the_slice_convention(ci_data):
    split = dataset.load_split(ci_data / "train.h5")
    spec = spec_for(split)
    assert spec.channels == ["v0", "v", "cos_theta", "sin_theta"]
    x, y = SliceSet(split, spec).batch(np.array([0, 7]))
    iv, it = np.unravel_index(7, split.grid.shape[2:])
    np.testing.assert_allclose(x[1, 0].numpy(), split.target[0, :, :, iv, it] / spec.value_scale, rtol=1e-6)
    np.testing.assert_allclose(y[1, 0].numpy(), split.value[0, :, :, iv, it] / spec.value_scale, rtol=1e-6)
    assert x[1, 2, 0, 0].item() == pytest.approx(np.cos(split.grid.axis(3)[it]), abs=1e-6)


TRIANGLE = np.array([(0.5, 0.2), (2.5, 0.8), (1.0, 2.0)])  # off-centre, no symmetry of its own


def _solve_polygon(grid, vertices):
    target = Polygon(tuple(map(tuple, vertices))).sdf(grid.states()[..., :2]).astype(np.float32)
    return solve(DynamicDubinsCar(), grid, target, max_horizon=3.0, tolerance=1e-9)[0]


@pytest.mark.parametrize("k, image", [(1, lambda p: np.column_stack([-p[:, 1], p[:, 0]])),  # quarter turn
                                      (4, lambda p: p * [1.0, -1.0])])  # reflection y -> -y
def test_symmetry_maps_a_solve_onto_the_solve_of_the_mapped_obstacle(k, image):
    """The augmentation's generators checked against real solves: V of the turned (mirrored) triangle
    equals the turned (mirrored) V of the triangle, slice by slice, with θ mapped too."""
    grid = car_grid((20, 20, 5, 8))
    value, mapped = _solve_polygon(grid, TRIANGLE), _solve_polygon(grid, image(TRIANGLE))
    thetas = grid.axis(3)
    for iv in range(grid.shape[2]):
        slices, theta = symmetry(value[:, :, iv].transpose(2, 0, 1), thetas, np.full(len(thetas), k))
        index = np.round((theta + np.pi) / grid.spacings[3]).astype(int) % grid.shape[3]
        np.testing.assert_allclose(slices, mapped[:, :, iv].transpose(2, 0, 1)[index], atol=2e-4)
    assert np.abs(value - mapped).max() > 0.5  # the obstacle really moved


def test_symmetry_group_and_augmented_training(ci_data, tmp_path):
    rng = np.random.default_rng(0)
    images, theta = rng.normal(size=(8, 6, 6)), rng.uniform(-np.pi, np.pi, 8)
    k = np.arange(8)
    assert len({o.tobytes() for o in symmetry(np.repeat(images[:1], 8, 0), theta, k)[0]}) == 8  # 8 elements
    inverse = np.where(k >= 4, k, (4 - k) % 4)  # reflections undo themselves, quarter turns by turning back
    back, theta_back = symmetry(*symmetry(images, theta, k), inverse)
    np.testing.assert_allclose(back, images)
    np.testing.assert_allclose(np.cos(theta_back - theta), 1.0)
    cfg = TrainConfig(data=str(ci_data), model_config=SMALL, epochs=1, slices_per_epoch=64, augment=True,
                      out=str(tmp_path / "aug"))
    train(cfg, progress=False)
    assert checkpoint.load_card(tmp_path / "aug")["training"]["augment"].startswith("D4")
    split = dataset.load_split(ci_data / "train.h5")
    narrow = SliceSet(dataclasses.replace(split, grid=split.grid.with_shape((20, 16, 5, 8))), spec_for(split))
    with pytest.raises(ValueError, match="square"):
        narrow.check_symmetric()


def test_training_reduces_the_loss_and_writes_a_card(trained):
    cfg, out = trained
    card = checkpoint.load_card(out)
    history = card["training"]["history"]
    assert len(history) == 3
    assert history[-1]["train_rel_l2"] < 0.8 * history[0]["train_rel_l2"]
    assert card["command"] == "test" and card["dataset"]["n_train"] == 4
    assert card["inputs"]["channels"][0] == "v0" and card["dynamics"]["a_max"] == 1.0
    assert checkpoint.paths(out)[0].stat().st_size < 10e6


def test_checkpoint_round_trip_is_exact(trained, tmp_path):
    _, out = trained
    model, card = checkpoint.load_model(out)
    x = torch.randn(2, 4, 20, 20)
    with torch.no_grad():
        before = model(x)
    checkpoint.save(tmp_path / "copy", {f"model.{k}": v for k, v in model.state_dict().items()}, card)
    again, _ = checkpoint.load_model(tmp_path / "copy")
    with torch.no_grad():
        assert torch.equal(again(x), before)


def test_pickles_truncated_and_mismatched_files_are_refused(trained, tmp_path):
    _, out = trained
    weights, card_path = checkpoint.paths(out)
    fake = tmp_path / "fake"
    (tmp_path / "fake.json").write_text(card_path.read_text())
    with open(tmp_path / "fake.safetensors", "wb") as fh:
        pickle.dump({"model.x": torch.zeros(3)}, fh)
    with pytest.raises(ValueError, match="safetensors"):
        checkpoint.load_model(fake)
    (tmp_path / "fake.safetensors").write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])
    with pytest.raises(ValueError, match="safetensors"):
        checkpoint.load_model(fake)
    card = json.loads(card_path.read_text())
    card["config"]["width"] = 16
    (tmp_path / "fake.json").write_text(json.dumps(card))
    (tmp_path / "fake.safetensors").write_bytes(weights.read_bytes())
    with pytest.raises(ValueError, match="does not match"):
        checkpoint.load_model(fake)
    with pytest.raises(ValueError, match="not found"):
        checkpoint.load_model(tmp_path / "missing")
    (tmp_path / "fake.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        checkpoint.load_model(fake)


def test_resume_continues_from_the_last_epoch(ci_data, tmp_path):
    out = tmp_path / "resume"
    cfg = TrainConfig(data=str(ci_data), model_config=SMALL, epochs=1, slices_per_epoch=64, out=str(out))
    cfg2 = TrainConfig(**{**cfg.__dict__, "epochs": 2})
    train(cfg, progress=False)
    with pytest.raises(ValueError, match="other settings"):
        train(cfg2, progress=False)  # a different schedule cannot resume this run
    train(TrainConfig(**{**cfg.__dict__, "max_minutes": 99.0}), progress=False)  # same settings: resumes, no-op
    assert len(checkpoint.load_card(out)["training"]["history"]) == 1


def test_nan_loss_stops_with_a_clear_message(ci_data, tmp_path):
    cfg = TrainConfig(data=str(ci_data), model_config=SMALL, epochs=1, slices_per_epoch=64, lr=1e30,
                      out=str(tmp_path / "nan"))
    with pytest.raises(TrainingDiverged, match="lower --lr"):
        train(cfg, progress=False)


def test_evaluation_reports_paper_columns(trained, ci_data, tmp_path):
    _, out = trained
    rows = evaluation.evaluate(out, ci_data, figures=tmp_path / "fig")
    row = rows[0]
    assert 0 < row["test_rel_l2"] < 2 and 0 <= row["test_iou"] <= 1 and 0 <= row["test_false_safe"] <= 1
    assert row["infer_ms"] > 0 and row["params_M"] > 0
    table = evaluation.record(row, tmp_path)
    assert "test_rel_l2" in table.read_text()
    assert list((tmp_path / "fig").glob("*.png"))
    from conftest import copy_model

    stem = copy_model(out, tmp_path)
    evaluation.record_in_card(stem, rows)  # the card keeps its metrics and gains the evaluation's
    metrics = checkpoint.load_typed(stem)[1].metrics
    assert metrics["test_rel_l2"] == row["test_rel_l2"] and metrics["headline"] == row["experiment"]
    assert "train_rel_l2_slices" in metrics and metrics["by_dataset"][row["experiment"]]["test_iou"] == row["test_iou"]


def test_unconverged_samples_only_on_request(trained, ci_data, tmp_path):
    import shutil

    import h5py

    data = tmp_path / "ci"
    shutil.copytree(ci_data, data)
    with h5py.File(data / "test.h5", "r+") as f:  # flag every test sample as not converged
        f["converged"][...] = False
        n_test = len(f["converged"])
    cfg = TrainConfig(data=str(data), model_config=SMALL, epochs=1, slices_per_epoch=64, out=str(tmp_path / "m"))
    with pytest.raises(ValueError, match="no converged samples.*--allow-unconverged"):
        train(cfg, progress=False)
    train(TrainConfig(**{**cfg.__dict__, "allow_unconverged": True}), progress=False)
    assert checkpoint.load_card(tmp_path / "m")["dataset"]["unconverged_used"] == n_test
    _, out = trained
    with pytest.raises(ValueError, match="no converged test samples"):
        evaluation.evaluate(out, data)
    row = evaluation.evaluate(out, data, unconverged=True)[0]
    assert row["n_train/n_test"].endswith(f"/{n_test} ({n_test} unconverged)")
    assert row["test_rel_l2_converged"] is None  # no converged test sample to average
    assert row["test_rms_error"] > 0 and 0 < row["test_edge_error_share"] < 1
    with h5py.File(data / "test.h5", "r+") as f:  # now only the first test sample converged
        f["converged"][0] = True
    converged_only = evaluation.evaluate(out, data)[0]
    row = evaluation.evaluate(out, data, unconverged=True)[0]
    assert converged_only["n_train/n_test"].endswith("/1")
    assert row["test_rel_l2_converged"] == converged_only["test_rel_l2"] > 0


def test_a_train_only_folder_joins_a_split_with_a_test_set(ci_data, tmp_path):
    """More scenarios from another seed with n_test 0 (no test.h5) add to the training set."""
    extra = tmp_path / "extra"
    base = dataset.load_config("ci")
    config = dataclasses.replace(base, n_train=1, n_test=0, seed=base.seed + 100)
    dataset.generate(config, extra, progress=False)
    assert not (extra / "test.h5").exists()
    cfg = TrainConfig(data=f"{ci_data},{extra}", model_config=SMALL, epochs=1, slices_per_epoch=64,
                      out=str(tmp_path / "m"))
    train(cfg, progress=False)
    card = checkpoint.load_card(tmp_path / "m")["dataset"]
    assert (card["n_train"], card["n_test"]) == (base.n_train + 1, base.n_test)
    assert card["test_folders"] == [str(ci_data)]  # evaluate/calibrate/simulate default to these
    assert [r["n_train/n_test"] for r in evaluation.evaluate(tmp_path / "m")] == [f"{base.n_train}/{base.n_test}"]
    with pytest.raises(ValueError, match="no test split among the datasets"):
        train(TrainConfig(**{**cfg.__dict__, "data": str(extra)}), progress=False)


def test_level_set_weight_counts_errors_near_zero_more(ci_data, tmp_path):
    target = torch.tensor([[[[0.0, 1.0]]]])
    near, far = torch.tensor([[[[0.1, 1.0]]]]), torch.tensor([[[[0.0, 1.1]]]])
    w = level_set_weight(target, 3.0, 0.2)
    assert relative_l2(near, target).item() == pytest.approx(0.1)
    assert relative_l2(near, target, w).item() == pytest.approx(0.2)  # sqrt(1 + 3) × the error at V∞ = 0
    assert relative_l2(far, target, w).item() == pytest.approx(0.1, rel=1e-6)  # weight ≈ 1 at V∞ = 1
    cfg = TrainConfig(data=str(ci_data), model_config=SMALL, epochs=2, slices_per_epoch=64, out=str(tmp_path / "m"),
                      level_set_weight=3.0, level_set_width=0.3)
    train(cfg, progress=False)
    card = checkpoint.load_card(tmp_path / "m")
    assert "weight 1 + 3.0" in card["training"]["loss"] and "0.3 m" in card["training"]["loss"]
    assert all(np.isfinite(h["train_rel_l2"]) for h in card["training"]["history"])
    with pytest.raises(ValueError, match="level-set weight"):
        train(TrainConfig(**{**cfg.__dict__, "level_set_width": 0.0}), progress=False)


def test_angle_pairs_are_next_angle_neighbours(ci_data):
    split = dataset.load_split(ci_data / "train.h5")
    parts = SliceUnion([SliceSet(split, spec_for(split))] * 2)
    index = np.arange(len(parts))
    pair = parts.angle_neighbour(index)
    x, xn = (parts.batch(i)[0].numpy() for i in (index, pair))
    np.testing.assert_array_equal(xn[:, 0], x[:, 0])  # same V0 slice
    np.testing.assert_array_equal(xn[:, 1], x[:, 1])  # same speed
    turn = np.arctan2(xn[:, 3, 0, 0], xn[:, 2, 0, 0]) - np.arctan2(x[:, 3, 0, 0], x[:, 2, 0, 0])
    np.testing.assert_allclose(np.cos(turn), np.cos(split.grid.spacings[3]), atol=1e-5)  # next angle, wrapping
    assert (pair // (len(parts) // 2) == index // (len(parts) // 2)).all()  # within the same dataset
    target = torch.tensor([0.0, 1.0, 1.0, 3.0])[:, None]  # slices (0, 1), their pairs (1, 3): changes 1, 2
    assert angle_difference_l2(torch.tensor([0.0, 1.0, 1.0, 2.0])[:, None], target).item() == pytest.approx(0.25)


def test_fine_tuning_starts_from_a_model_and_adds_the_angle_pair_loss(trained, ci_data, tmp_path):
    cfg, base = trained
    tuned = TrainConfig(data=str(ci_data), model_config=SMALL, epochs=1, slices_per_epoch=256, lr=1e-3,
                        out=str(tmp_path / "tuned"), init=str(base), angle_pair_weight=1.0)
    train(tuned, progress=False)
    card = checkpoint.load_card(tmp_path / "tuned")
    assert card["training"]["init"]["model"] == str(base) and card["training"]["init"]["command"] == "test"
    assert "V(theta_k+1) - V(theta_k)" in card["training"]["loss"]
    own = sum(h["wall_s"] for h in card["training"]["history"])
    assert card["training"]["wall_s"] == pytest.approx(own + checkpoint.load_card(base)["training"]["wall_s"], abs=0.1)
    first_epoch_from_scratch = checkpoint.load_card(base)["training"]["history"][0]["train_rel_l2"]
    assert card["training"]["history"][0]["train_rel_l2"] < 0.8 * first_epoch_from_scratch  # it did start trained
    with pytest.raises(ValueError, match="same --model"):
        train(TrainConfig(**{**tuned.__dict__, "model_config": {**SMALL, "width": 12}, "out": str(tmp_path / "x")}),
              progress=False)
    with pytest.raises(ValueError, match="even batch"):
        train(TrainConfig(**{**tuned.__dict__, "batch": 15}), progress=False)


def test_metrics_are_right_on_known_tables():
    truth = np.array([-1.0, -1.0, 1.0, 1.0])
    m = evaluation.table_metrics(np.array([-1.0, 1.0, 1.0, -1.0]), truth)
    assert m["iou"] == pytest.approx(1 / 3) and m["false_safe"] == pytest.approx(0.5)
    assert m["rms_error"] == pytest.approx(np.sqrt(2.0))
    assert evaluation.table_metrics(truth, truth) == {"rel_l2": 0.0, "rms_error": 0.0, "iou": 1.0, "false_safe": 0.0}
    table = np.zeros((6, 6, 2))
    error = table.copy()
    error[0, 0], error[3, 3] = 1.0, 1.0  # one unit of error on the edge, one inside
    assert evaluation.edge_error_share(error, table) == pytest.approx(0.5)
    error[3, 3] = 0.0
    assert evaluation.edge_error_share(error, table) == 1.0 and evaluation.edge_error_share(table, table) == 0.0


def test_learned_value_function_gives_value_and_gradient(trained):
    _, out = trained
    vf = LearnedValueFunction(out, device="cpu")
    xy = vf.window_points((1.0, 2.0))
    v0 = np.hypot(xy[..., 0] - 1.0, xy[..., 1] - 3.0) - 0.8  # a disk 1 m north of the window centre
    table = vf.local_table(v0, (1.0, 2.0), 0.5, 0.3)
    state = np.array([[1.0, 2.0, 0.5, 0.3]])
    value, grad = table.value(state), table.gradient(state)
    assert np.isfinite(value).all() and grad.shape == (1, 4) and np.isfinite(grad).all()
    v0_at_state = RegularGridInterpolator((xy[:, 0, 0], xy[0, :, 1]), v0)(state[:, :2])[0]
    assert value[0] <= v0_at_state + 1e-6  # V ≤ V0 by construction
    # the stencil is one (v, θ) cell centred on the state: V there is the mean of its 4 corner slices,
    # ∂V/∂θ their central difference over one heading step
    dv, dth = vf.grid.spacings[2:]
    assert table.grid.shape[2:] == (2, 2) and np.allclose(table.grid.spacings[2:], (dv, dth))
    assert np.allclose([table.grid.lo[2] + dv / 2, table.grid.lo[3] + dth / 2], [0.5, 0.3])
    vv, tt = np.meshgrid([0.5 - dv / 2, 0.5 + dv / 2], [0.3 - dth / 2, 0.3 + dth / 2], indexing="ij")
    corners = [RegularGridInterpolator((xy[:, 0, 0], xy[0, :, 1]), sl)(state[:, :2])[0]
               for sl in vf.predict(v0, vv.ravel(), tt.ravel())]  # order (v, θ): (lo, lo), (lo, hi), ...
    assert value[0] == pytest.approx(np.mean(corners), abs=1e-5)
    assert grad[0, 3] == pytest.approx((corners[1] + corners[3] - corners[0] - corners[2]) / (2 * dth), abs=1e-4)
    with pytest.raises(ValueError, match="finite"):
        vf.predict(np.full((20, 20), np.nan), np.zeros(1), np.zeros(1))


def test_inflation_at_the_output_runs_the_model_on_l(trained, ci_data):
    """V∞[l − r] = V∞[l] − r (test_dataset checks it on real solves): with ``inflation_at="output"`` the
    model reads l and r comes off its output; by default ("input", as brt_node) it reads l − r."""
    from hjrno_ros.studies import held_out

    _, out = trained
    r = np.float32(0.23)
    plain = dataset.load_split(ci_data / "train.h5")
    spec = spec_for(plain)
    model, _ = checkpoint.load_model(out)
    with torch.no_grad():
        base = evaluation.predict_table(model, spec, plain.grid, plain.target[0])
        lowered = evaluation.predict_table(model, spec, plain.grid, plain.target[0] - r, shift=float(r))
    np.testing.assert_allclose(lowered, base - r, atol=1e-5)
    solved = [held_out.Solved("ci/0", plain.scenarios[0], plain.grid, plain.target[0] - r, plain.value[0] - r,
                              float(r))]
    at_input, at_output = (held_out.predict(out, solved, inflation_at=m)[0] for m in held_out.INFLATION_AT)
    np.testing.assert_allclose(at_output, np.minimum(base, plain.target[0]) - r, atol=1e-5)
    assert np.abs(at_input - at_output).max() > 1e-3
    with pytest.raises(ValueError, match="inflation_at"):
        held_out.predict(out, solved, inflation_at="both")


def test_learned_value_function_follows_the_cards_symmetry_average(trained, tmp_path):
    """With ``symmetry_average`` in the card, the node's core predicts with the averaged model: a map
    turned a quarter about the window centre, heading turned with it, gives the turned prediction."""
    _, out = trained
    local = copy_model(out, tmp_path)
    checkpoint.update_card(local, {"symmetry_average": True})
    plain, averaged = LearnedValueFunction(out, device="cpu"), LearnedValueFunction(local, device="cpu")
    xy = averaged.window_points((0.0, 0.0))
    v0 = np.hypot(xy[..., 0] - 1.5, xy[..., 1] - 0.5) - 0.8
    base = averaged.predict(v0, np.array([0.5]), np.array([0.3]))[0]
    turned = averaged.predict(np.rot90(v0).copy(), np.array([0.5]), np.array([0.3 + np.pi / 2]))[0]
    np.testing.assert_allclose(turned, np.rot90(base), atol=1e-5)
    assert np.abs(plain.predict(v0, np.array([0.5]), np.array([0.3]))[0] - base).max() > 1e-3


def test_parametric_diagonal_figure(tmp_path):
    import dataclasses

    from hjrno_ros.learning.operators import build_model

    config = dataclasses.replace(dataset.load_config("ci"), name="ci_parametric", family="parametric",
                                 parametric_grid=2, n_train=4, n_test=3)
    dataset.generate(config, tmp_path / "data", progress=False)
    test = dataset.load_split(tmp_path / "data" / "test.h5")
    spec = spec_for(test)
    assert spec.channels[-2:] == ["a_max", "kappa_max"]
    diag = np.array([[s.params["a_max"], s.params["kappa_max"]] for s in test.scenarios])
    assert np.allclose(diag[:, 0], diag[:, 1])  # the test split lies on the diagonal
    model = build_model("fno", in_channels=len(spec.channels), **SMALL).eval()
    path = evaluation.diagonal_figure(model, "fno", spec, test, tmp_path / "diag.png")
    assert path.stat().st_size > 10_000


def test_ensemble_predicts_the_members_mean_and_refuses_unlike_members(trained, ci_data, tmp_path):
    """``hjrno ensemble``: one checkpoint whose output is the mean of its members' (with ``--pessimism`` k,
    mean − k·std), usable like any model."""
    from hjrno_ros.learning import combine

    _, fno = trained
    cnn = tmp_path / "cnn"
    train(TrainConfig(data=str(ci_data), model="cnn", model_config={"channels": 4, "depth": 2}, epochs=1,
                      slices_per_epoch=64, batch=16, out=str(cnn)), progress=False, command="test")
    ens = tmp_path / "ens"
    combine.combine([str(fno), str(cnn)], ens, "test")
    model, card = checkpoint.load_model(ens)
    (a, _), (b, _) = checkpoint.load_model(fno), checkpoint.load_model(cnn)
    x = torch.randn(2, 4, 20, 20)
    with torch.no_grad():
        torch.testing.assert_close(model(x), (a(x) + b(x)) / 2, rtol=0, atol=1e-6)
        assert (a(x) - b(x)).abs().max() > 1e-3  # the mean differs from either member
    assert card["kind"] == "ensemble" and card["epsilon"] is None and [m["kind"] for m in card["members"]] == [
        "fno", "cnn"]
    assert card["parameters"] == sum(checkpoint.load_card(s)["parameters"] for s in (fno, cnn))
    value = LearnedValueFunction(ens, device="cpu")  # the node's core reads it like any model
    xy = value.window_points((0.0, 0.0))
    assert np.isfinite(value.predict(np.hypot(xy[..., 0], xy[..., 1]) - 0.8, np.array([0.5]), np.array([0.3]))).all()
    row = evaluation.evaluate(str(ens), str(ci_data))[0]
    assert row["model"].startswith("ensemble") and 0 < row["test_rel_l2"] < 10
    from hjrno_ros.cli import main

    assert main(["ensemble", "--model", str(fno), "--model", str(cnn), "--pessimism", "1.5", "--out",
                 str(tmp_path / "pessimistic")]) == 0
    low, low_card = checkpoint.load_model(tmp_path / "pessimistic")
    with torch.no_grad():  # the std of two is half their difference
        torch.testing.assert_close(low(x), (a(x) + b(x)) / 2 - 1.5 * (a(x) - b(x)).abs() / 2, rtol=0, atol=1e-5)
    assert low_card["config"]["pessimism"] == 1.5 and card["config"]["pessimism"] == 0.0
    checkpoint.update_card(ens, {"member_frames": [[0], [2, 5]]})  # the cnn predicts turned and mirrored
    framed, _ = checkpoint.load_model(ens)
    b_framed = SymmetryAverage(b, 2, 3, elements=(2, 5))
    with torch.no_grad():
        torch.testing.assert_close(framed(x), (a(x) + b_framed(x)) / 2, rtol=0, atol=1e-5)
        assert (b_framed(x) - b(x)).abs().max() > 1e-3
    for bad in ([[0]], [[0], [8]], [[0], []], [[0], [1, 1]]):
        checkpoint.update_card(ens, {"member_frames": bad})
        with pytest.raises(ValueError, match="member_frames"):
            checkpoint.load_model(ens)
    checkpoint.update_card(ens, {"member_frames": None})

    with pytest.raises(ValueError, match="at least 2"):
        combine.combine([str(fno)], tmp_path / "one", "test")
    with pytest.raises(ValueError, match="cannot itself be an ensemble"):
        combine.combine([str(ens), str(fno)], tmp_path / "nested", "test")
    (tmp_path / "other").mkdir()
    other = copy_model(cnn, tmp_path / "other")
    card_other = checkpoint.load_card(other)
    checkpoint.update_card(other, {"dataset": {**card_other["dataset"], "digests": ["0000000000000000"]}})
    with pytest.raises(ValueError, match="different datasets"):
        combine.combine([str(fno), str(other)], tmp_path / "bad", "test")
    checkpoint.update_card(other, {"dataset": card_other["dataset"],
                                   "inputs": {**card_other["inputs"], "value_scale": 123.0}})
    with pytest.raises(ValueError, match="'inputs'"):
        combine.combine([str(fno), str(other)], tmp_path / "bad", "test")
    assert not checkpoint.paths(tmp_path / "bad")[0].exists()  # nothing written for a refused ensemble
