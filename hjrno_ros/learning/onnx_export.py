"""A trained operator as an ONNX file, so inference needs onnxruntime and not torch.

The graph is the model's own ``forward`` (coordinate channels, output prior, ensemble mean, symmetry
averaging all inside): input ``x`` float32 [batch, in_channels, nx, ny], output ``y`` float32
[batch, out_channels, nx, ny].  The batch is free (axis 0 is named "batch"); the x-y grid is fixed
at the shape it was exported for (the card's grid).  Exported with ``torch.onnx.export(dynamo=True)``
(torch.export, then onnxscript) at opset :data:`OPSET`; the FNO exports because its truncated Fourier
transform is real matmuls (:func:`hjrno_ros.learning.operators.fno.dft_matrices`).  Training stays
in torch.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import torch

from hjrno_ros.core.atomic import atomic_write

OPSET = 18  # torch's dynamo exporter writes opset 18 natively (onnxscript's torchlib)
INPUT, OUTPUT, BATCH = "x", "y", "batch"


def export_onnx(model: torch.nn.Module, in_channels: int, shape: tuple[int, int], path: str | Path) -> dict:
    """Write ``model`` to ``path`` as ONNX (atomically: the old file or the new one, never a partial one) for
    inputs [batch, ``in_channels``, *``shape``]; returns the card's record of the file: name, sha256, input
    and output names and shapes, opset.  ValueError where the exported graph's shapes are not those (a model
    whose code fixes the batch size); the model is left in the train/eval mode it had."""
    path = Path(path)
    nx, ny = (int(n) for n in shape)
    device = next(model.parameters()).device
    example = torch.randn(2, in_channels, nx, ny, generator=torch.Generator().manual_seed(0)).to(device)
    training = model.training
    model.eval()
    try:
        with torch.no_grad():
            out_channels = int(model(example).shape[1])
        # batch 2 in the example: torch.export fixes dims of size 0 and 1; opt_einsum's contraction order
        # (the TNO) would fix the batch too, so the plain left-to-right order is traced instead
        with torch.backends.opt_einsum.flags(enabled=False):
            program = torch.onnx.export(model, (example,), dynamo=True, input_names=[INPUT],
                                        output_names=[OUTPUT], opset_version=OPSET, verbose=False,
                                        dynamic_shapes=({0: torch.export.Dim(BATCH, min=1)},))
    finally:
        model.train(training)
    proto = program.model_proto
    want = {INPUT: [BATCH, in_channels, nx, ny], OUTPUT: [BATCH, out_channels, nx, ny]}
    got = {v.name: [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim]
           for v in (*proto.graph.input, *proto.graph.output)}
    if got != want:
        raise ValueError(f"the exported ONNX graph has inputs/outputs {got}, expected {want}")
    for node in (*proto.graph.node, *(n for f in proto.functions for n in f.node)):
        del node.metadata_props[:]  # torch's debug notes (stack traces with local paths): the same model, same file
    data = proto.SerializeToString()
    atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))
    opset = next(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx"))
    return {"file": path.name, "sha256": hashlib.sha256(data).hexdigest(),
            "input": {"name": INPUT, "shape": want[INPUT]}, "output": {"name": OUTPUT, "shape": want[OUTPUT]},
            "opset": int(opset)}


def check_export(model: torch.nn.Module, path: str | Path, x: np.ndarray) -> float:
    """Max |torch - onnxruntime| (CPUExecutionProvider) of ``model`` and the ONNX file at ``path`` on inputs ``x``."""
    import onnxruntime

    x = np.ascontiguousarray(x, np.float32)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (onnx_out,) = session.run([OUTPUT], {INPUT: x})
    device = next(model.parameters()).device
    training = model.training
    model.eval()
    try:
        with torch.no_grad():
            torch_out = model(torch.from_numpy(x).to(device)).cpu().numpy()
    finally:
        model.train(training)
    if onnx_out.shape != torch_out.shape:
        raise ValueError(f"ONNX output {onnx_out.shape}, torch output {torch_out.shape}")
    return float(np.max(np.abs(onnx_out - torch_out))) if x.size else 0.0


EXPORT_TOLERANCE = 1e-4  # max |torch - onnxruntime| accepted on a window of a signed distance (measured ~1e-6)


def export_model(stem: str | Path) -> dict:
    """Export the model at ``stem`` as loaded for inference (its card's symmetry averaging and member frames) to
    ``<stem>.onnx``, check onnxruntime against torch on a window of a signed distance, and record the file in the
    card (``onnx``, with what it was exported from); returns the record.  ValueError, one line, on a mismatch."""
    from hjrno_ros.core.model_card import paths
    from hjrno_ros.inference.onnx_operator import exported_from
    from hjrno_ros.learning import checkpoint
    from hjrno_ros.learning.slices import InputSpec

    model, card = checkpoint.load_typed(stem, "cpu")
    spec = InputSpec.from_dict(card.inputs)
    shape = tuple(int(n) for n in card.grid.shape[:2])
    path = paths(stem)[1].with_suffix(".onnx")
    record = export_onnx(model, spec.in_channels, shape, path)
    gap = check_export(model, path, probe_inputs(spec, card.grid.lo[:2], card.grid.hi[:2], shape, card.dynamics))
    if not gap <= EXPORT_TOLERANCE:
        path.unlink(missing_ok=True)
        raise ValueError(f"{path}: onnxruntime differs from torch by {gap:.3g} (> {EXPORT_TOLERANCE:g}); not recorded")
    record["network"] = exported_from(stem, card)
    checkpoint.update_card(stem, {"onnx": record})
    return record


def refresh_export(stem: str | Path) -> dict | None:
    """Re-export a model whose card lists an ONNX export that no longer matches it (new weights, or symmetry
    averaging or member frames changed by calibration); the new record, or None when nothing was to do."""
    from hjrno_ros.core.model_card import ModelCard
    from hjrno_ros.inference.onnx_operator import exported_from

    card = ModelCard.load(stem)
    if card.onnx is None or card.onnx.network == exported_from(stem, card):
        return None
    return export_model(stem)


def probe_inputs(spec, lo, hi, shape: tuple[int, int], dynamics) -> np.ndarray:
    """Two input windows (batch 2) of a signed distance to two disks, at a low and a high speed and two headings,
    with the card's own parameter channels: what the export is checked on."""
    import dataclasses

    from hjrno_ros.core.model_inputs import param_value

    x = np.linspace(lo[0], hi[0], shape[0])[:, None]
    y = np.linspace(lo[1], hi[1], shape[1])[None, :]
    span = min(hi[0] - lo[0], hi[1] - lo[1])
    v0 = np.minimum(np.hypot(x - 0.2 * span, y) - 0.1 * span, np.hypot(x + 0.25 * span, y - 0.2 * span) - 0.05 * span)
    v_lo, v_hi = spec.v_range
    values = dataclasses.asdict(dynamics)
    params = np.array([[param_value(values, n) for n in spec.param_ranges]] * 2, np.float32) \
        if spec.param_ranges else None
    return spec.array(np.stack([v0, v0.T if shape[0] == shape[1] else v0]).astype(np.float32),
                      np.array([v_lo + 0.25 * (v_hi - v_lo), v_hi]), np.array([0.3, -2.0]), params)
