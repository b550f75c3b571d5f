"""The typed model card: the bundled cards load, every problem is one ValueError line naming the field,
ε is worked out in one place, and the weights must take the inputs the card lists."""

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

from hjrno_ros.core.dynamics import CarParams
from hjrno_ros.core.model_card import DEFAULT_EPSILON, ModelCard, load_card
from hjrno_ros.learning import checkpoint

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ("paper_cnn", "v5")


@pytest.fixture(scope="module")
def base() -> dict:
    """The bundled v5 card without its calibration and ONNX export: a plain, valid car card."""
    card = load_card(ROOT / "models" / "v5")
    for key in ("epsilon", "refine_epsilon", "refine_calibration", "calibration", "member_frames", "onnx"):
        card.pop(key, None)
    return card


def edited(card: dict, path: str, value=None, delete: bool = False) -> dict:
    """A deep copy of ``card`` with the dotted ``path`` set to ``value`` (or deleted)."""
    out = copy.deepcopy(card)
    *parents, last = path.split(".")
    d = out
    for key in parents:
        d = d[key]
    if delete:
        del d[last]
    else:
        d[last] = value
    return out


def refused(card: dict, match: str) -> str:
    with pytest.raises(ValueError, match=match) as err:
        ModelCard.from_dict(card, "m.json")
    text = str(err.value)
    assert "\n" not in text and text.startswith("m.json"), text
    return text


@pytest.mark.parametrize("name", BUNDLED)
def test_the_bundled_cards_load(name):
    card = ModelCard.load(ROOT / "models" / name)
    assert card.kind == "ensemble" and card.family == "car" and card.source == ROOT / "models" / f"{name}.json"
    assert card.dynamics == CarParams(a_max=1.0, kappa_max=1.0, d_max=0.1, v_min=0.0, v_max=1.0)
    assert card.grid.shape == (32, 32, 9, 16) and card.grid.periodic == (3,) and card.window == (10.0, 10.0)
    assert card.inputs["channels"] == ["v0", "v", "cos_theta", "sin_theta"] and card.config["in_channels"] == 4
    assert 0.1 < card.epsilon < 0.3 and card.margin() == card.epsilon and card.parameters == 790131
    assert card.data == load_card(ROOT / "models" / name) and card.training and card.dataset["folders"]
    if name == "paper_cnn":
        assert card.member_frames == [[0, 5], [1, 6], [3, 4]] and card.refine_horizon == 16.0
        assert card.refined_margin(16.0) == card.refine_epsilon != card.epsilon == card.refined_margin(15.0)
    else:
        assert card.member_frames is None and card.refine_epsilon is None and card.refine_horizon is None
        assert card.refined_margin(100.0) == card.epsilon


def test_reading_a_card_imports_no_torch_and_held_out_no_calibration():
    code = ("import sys; from hjrno_ros.core.model_card import ModelCard; "
            f"ModelCard.load({str(ROOT / 'models' / 'paper_cnn')!r}); assert 'torch' not in sys.modules; "
            "import hjrno_ros.studies.held_out; assert 'hjrno_ros.studies.calibration' not in sys.modules; "
            "import hjrno_ros.learning.operators.ensemble as e; assert sorted(e.MODELS) == ['cnn', 'fno', 'tno']")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert run.returncode == 0, run.stderr


@pytest.mark.parametrize("path", [
    "kind", "config", "inputs", "grid", "dynamics", "inputs.kind", "inputs.channels", "config.in_channels",
    "grid.lo", "grid.hi", "grid.shape", "dynamics.a_max", "dynamics.kappa_max", "dynamics.d_max", "dynamics.v_min",
    "dynamics.v_max", "window.lo", "window.hi", "window.shape"])
def test_a_missing_field_is_one_line_naming_it(base, path):
    refused(edited(base, path, delete=True), rf"field '{path}' is missing")


def test_a_card_file_missing_a_field_names_it(base, tmp_path):
    (tmp_path / "m.json").write_text(json.dumps(edited(base, "dynamics.a_max", delete=True)))
    with pytest.raises(ValueError, match=r"field 'dynamics\.a_max' is missing"):
        ModelCard.load(tmp_path / "m")
    (tmp_path / "m.json").write_text(json.dumps(edited(base, "grid", delete=True)))
    with pytest.raises(ValueError, match=r"lacks \['grid'\]"):
        ModelCard.load(tmp_path / "m")


@pytest.mark.parametrize("path, value, field", [
    ("kind", 3, "kind"),
    ("kind", "transformer", "kind"),
    ("config", [], "config"),
    ("config.in_channels", 4.0, "config.in_channels"),
    ("inputs", "car", "inputs"),
    ("inputs.kind", "boat", "inputs.kind"),
    ("inputs.channels", "v0,v", "inputs.channels"),
    ("inputs.channels", [1, 2, 3, 4], "inputs.channels"),
    ("inputs.v_range", "0..1", "inputs.v_range"),
    ("grid", [1, 2], "grid"),
    ("grid.shape", [32.5, 32, 9, 16], "grid.shape"),
    ("grid.shape", "32x32x9x16", "grid.shape"),
    ("grid.lo", [-5.0, -5.0, "0", -3.14], "grid.lo"),
    ("grid.lo", [5.0, -5.0, 0.0, -3.14], "grid"),  # lo > hi
    ("grid.periodic", [], "grid"),
    ("dynamics", None, "dynamics"),
    ("dynamics.a_max", "1.0", "dynamics.a_max"),
    ("dynamics.a_max", True, "dynamics.a_max"),
    ("dynamics.a_max", -1.0, "dynamics"),
    ("dynamics.d_max", float("nan"), "dynamics.d_max"),
    ("window", [10, 10], "window"),
    ("window.shape", [32, 31], "window.shape"),
    ("window.hi", [5.0, 6.0], "window.hi"),
    ("epsilon", "0.2", "epsilon"),
    ("epsilon", -0.1, "epsilon"),
    ("refine_epsilon", float("inf"), "refine_epsilon"),
    ("symmetry_average", "yes", "symmetry_average"),
    ("member_frames", {"0": [1]}, "member_frames"),
    ("metrics", [], "metrics"),
    ("dataset", "ci", "dataset"),
    ("training", [], "training"),
    ("parameters", 1.5, "parameters"),
    ("command", ["hjrno"], "command"),
])
def test_a_field_of_the_wrong_type_or_value_is_one_line_naming_it(base, path, value, field):
    refused(edited(base, path, value), rf"field '{field}'")


def test_not_a_card(base):
    refused(edited(base, "format", "hjrno-model-0"), "not an hjrno model card")
    with pytest.raises(ValueError, match="not an hjrno model card"):
        ModelCard.from_dict([], "m.json")


def test_the_speed_axis_must_match_the_dynamics_and_the_inputs(base):
    refused(edited(base, "dynamics.v_max", 2.0), r"field 'grid' speed axis \[0, 1\] differs from dynamics")
    refused(edited(base, "dynamics.v_min", 0.5), "speed axis")
    refused(edited(base, "inputs.v_range", [0.0, 2.0]), r"field 'inputs.v_range'")
    assert ModelCard.from_dict(edited(base, "inputs.v_range", [0, 1])).inputs["v_range"] == [0, 1]


def test_the_grid_must_be_a_car_grid_and_agree_with_the_inputs(base):
    air = edited(base, "grid", {"lo": [-5, -5, -3.14], "hi": [5, 5, 3.14], "shape": [20, 20, 12], "periodic": [2]})
    refused(air, r"field 'grid' must be an \(x, y, v, theta\) grid")
    refused(edited(base, "config.in_channels", 5), r"field 'config.in_channels' is 5, but inputs.channels lists 4")
    refused(edited(base, "inputs.channels", ["v0", "v", "cos_theta"]), "field 'config.in_channels'")


def test_an_air3d_card_reads_its_own_grid_and_dynamics(base):
    """``hjrno evaluate`` loads Air3D models too: (x, y, ψ) grid, Air3DParams; the filter refuses them later."""
    from hjrno_ros.core.dynamics import Air3DParams
    from hjrno_ros.core.grids import air3d_grid

    g = air3d_grid((21, 17, 12))
    card = {**base, "config": {**base["config"], "in_channels": 3}, "grid": g.as_dict(),
            "dynamics": Air3DParams().as_dict(),
            "inputs": {"kind": "air3d", "value_scale": 13.0, "channels": ["v0", "cos_psi", "sin_psi"]},
            "window": {"lo": list(g.lo[:2]), "hi": list(g.hi[:2]), "shape": list(g.shape[:2])}}
    air = ModelCard.from_dict(card)
    assert air.family == "air3d" and air.dynamics == Air3DParams() and air.window == (26.0, 20.0)
    refused(edited(card, "dynamics.pursuer_speed", delete=True), "field 'dynamics.pursuer_speed' is missing")
    refused(edited(card, "grid", base["grid"]), r"field 'grid' must be an \(x, y, psi\) grid")


def test_optional_fields_default(base):
    card = ModelCard.from_dict({k: v for k, v in base.items() if k not in (
        "window", "metrics", "dataset", "training", "parameters", "command", "symmetry_average")})
    assert (card.symmetry_average, card.metrics, card.dataset, card.training, card.parameters, card.command) == (
        False, {}, {}, {}, None, None)
    assert card.window == (10.0, 10.0) and str(card.source) == "<card>"


def test_margin_and_refined_margin(base):
    plain = ModelCard.from_dict(base)
    assert plain.epsilon is None and plain.margin() == DEFAULT_EPSILON == 0.1 and plain.refined_margin(5.0) is None
    calibrated = ModelCard.from_dict({**base, "epsilon": 0.2})
    assert calibrated.margin() == 0.2 == calibrated.refined_margin(0.0) == calibrated.refined_margin(99.0)
    orphan = ModelCard.from_dict({**base, "epsilon": 0.2, "refine_epsilon": 0.12})  # no stage: not usable
    assert orphan.refine_epsilon is None and orphan.refined_margin(99.0) == 0.2
    refined = ModelCard.from_dict({**base, "epsilon": 0.2, "refine_epsilon": 0.12,
                                   "refine_calibration": {"horizon_s": 16}})
    assert (refined.refine_epsilon, refined.refine_horizon) == (0.12, 16.0)
    assert refined.refined_margin(15.9) == 0.2 and refined.refined_margin(16.0) == 0.12 == refined.refined_margin(40)
    assert refined.margin() == 0.2  # the operator's own ε is untouched by the refined one
    uncalibrated_refined = ModelCard.from_dict({**base, "refine_epsilon": 0.12, "refine_calibration": {"horizon_s": 1}})
    assert uncalibrated_refined.refined_margin(0.5) is None and uncalibrated_refined.refined_margin(1.0) == 0.12


def tiny_model(base: dict, tmp_path: Path, **card_changes) -> Path:
    """An untrained 4-channel CNN saved with ``base``'s inputs, grid and dynamics (and ``card_changes``)."""
    from hjrno_ros.learning.operators import build_model

    model = build_model("cnn", in_channels=4, channels=4, depth=2)
    card = {k: base[k] for k in ("inputs", "grid", "window", "dynamics")}
    card.update(kind="cnn", config=model.config, dataset={"folders": ["ci"]}, **card_changes)
    checkpoint.save(tmp_path / "m", {f"model.{k}": v for k, v in model.state_dict().items()}, card)
    return tmp_path / "m"


def test_the_weights_must_take_the_inputs_the_card_lists(base, tmp_path):
    stem = tiny_model(base, tmp_path)
    model, card = checkpoint.load_typed(stem)
    assert model.in_channels == 4 and card.kind == "cnn" and checkpoint.load_model(stem)[1] == card.data
    assert checkpoint.folders_with_test_split(card) == ["ci"] == checkpoint.folders_with_test_split(card.data)
    five = {**base["inputs"], "param_ranges": {"a_max": [0.5, 1.5]},
            "channels": ["v0", "v", "cos_theta", "sin_theta", "a_max"]}
    checkpoint.update_card(stem, {"inputs": five, "config": {**card.config, "in_channels": 5}})
    with pytest.raises(ValueError, match=r"m.safetensors does not match the architecture in its model card \(.*"
                                         r"weights \(4, 6, 3, 3\), card \(4, 7, 3, 3\)") as err:
        checkpoint.load_model(stem)
    assert "\n" not in str(err.value)
    swapped = {**base["inputs"], "channels": ["v", "v0", "cos_theta", "sin_theta"]}
    checkpoint.update_card(stem, {"inputs": swapped, "config": card.config})
    with pytest.raises(ValueError, match=r"field 'inputs.channels' is \['v', 'v0'"):
        checkpoint.load_model(stem)
    checkpoint.update_card(stem, {"inputs": base["inputs"], "dynamics": {"kappa_max": 1.0}})
    with pytest.raises(ValueError, match=r"field 'dynamics.a_max' is missing"):  # the old code's silent 1.0
        checkpoint.load_model(stem)


@pytest.mark.parametrize("field, change", [
    ("grid", lambda c: (c["grid"].update(shape=[64, 64, 9, 16]), c["window"].update(shape=[64, 64]))),
    ("grid", lambda c: (c["grid"].update(lo=[-10.0, -10.0, 0.0, c["grid"]["lo"][3]], hi=[10.0, 10.0, 1.0,
                                                                                       c["grid"]["hi"][3]]),
                        c["window"].update(lo=[-10.0, -10.0], hi=[10.0, 10.0]))),
    ("dynamics", lambda c: c["dynamics"].update(a_max=2.0)),
])
def test_a_card_that_contradicts_what_the_weights_were_trained_for_is_refused(tmp_path, field, change):
    """The weights record the grid, window, dynamics and inputs they were trained for (safetensors
    metadata): a card edited afterwards (a 64 x 64 grid or a 20 m window over 32 x 32, 10 m weights) is
    refused with one line naming the field, instead of filtering on a wrong scale."""
    from conftest import copy_model

    stem = copy_model(ROOT / "models" / "default", tmp_path)
    checkpoint.load_typed(stem)  # unchanged: loads
    card = load_card(stem)
    change(card)
    if card["grid"]["shape"][:2] != [32, 32]:  # the ONNX export's shapes refuse the new grid first
        checkpoint.paths(stem)[1].write_text(json.dumps(card))
        with pytest.raises(ValueError, match="field 'onnx.input.shape'"):
            checkpoint.load_typed(stem)
    card.pop("onnx")  # the weights' own record, without the export
    checkpoint.paths(stem)[1].write_text(json.dumps(card))
    with pytest.raises(ValueError, match=f"field '{field}'") as err:
        checkpoint.load_typed(stem)
    assert "\n" not in str(err.value)
