"""A card's network run by onnxruntime, without torch: the node's operator when its card lists an ONNX export.

:class:`OnnxOperator` checks the file against its card before a session starts (its SHA-256, the input and output
names and shapes) and refuses a contradiction with one line; CUDA's execution provider is used where onnxruntime
has it and the device asks for it ('' = cuda when available), else the CPU.  :func:`onnx_values` makes the card's
value source from it (:class:`~hjrno_ros.core.operator_values.OperatorValues`)."""

from __future__ import annotations

import ctypes
import hashlib
from pathlib import Path

import numpy as np

from hjrno_ros.core.model_card import ModelCard, OnnxFile, paths
from hjrno_ros.core.operator_values import OperatorValues

CPU, CUDA = "CPUExecutionProvider", "CUDAExecutionProvider"


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def trim_heap() -> None:
    """Hand the heap's free pages back to the OS (glibc's ``malloc_trim``): a session optimises its graph in ~20 MB
    of temporaries that glibc would otherwise keep for the life of the node (the default card's session: 42 MB of
    RSS before, 19 MB after).  Nothing where the C library has no ``malloc_trim``."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


def providers(device: str, available: list[str]) -> list:
    """onnxruntime's providers for the node's ``device``: '' = CUDA where available, then CPU; cpu; cuda[:N]."""
    if device in ("", "cpu"):
        return [CUDA, CPU] if device == "" and CUDA in available else [CPU]
    if device == "cuda" or device.startswith("cuda:") and device[5:].isdigit():
        if CUDA not in available:
            raise ValueError(f"device {device!r}: this onnxruntime has no CUDA provider (providers: {available})")
        return [(CUDA, {"device_id": int(device[5:] or 0)}), CPU]
    raise ValueError(f"device must be '', cpu, cuda or cuda:N, got {device!r}")


class OnnxOperator:
    """The network in ``path`` as described by its card's ``entry``; called with inputs (B, C, Nx, Ny) float32."""

    def __init__(self, path: Path, entry: OnnxFile, device: str = "", threads: int = 1) -> None:
        if not path.is_file():
            raise ValueError(f"{path}: the ONNX file its card lists is missing")
        digest = file_sha256(path)
        if digest != entry.sha256:
            raise ValueError(f"{path}: its SHA-256 {digest[:12]}… differs from its card's {entry.sha256[:12]}…: the "
                             "file is not the card's export (hjrno export-onnx writes both)")
        import onnxruntime as ort  # the node's only inference dependency

        options = ort.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads, options.log_severity_level = threads, 1, 3
        chosen = providers(device, ort.get_available_providers())
        try:
            self.session = ort.InferenceSession(str(path), options, providers=chosen)
        except Exception as err:  # onnxruntime's own error types: a file it cannot run
            raise ValueError(f"{path}: onnxruntime cannot load it: {str(err).splitlines()[0][:200]}") from None
        trim_heap()
        self.input, self.output = self._checked(path, entry)

    def _checked(self, path: Path, entry: OnnxFile) -> tuple[str, str]:
        """The input and output names, after checking the graph's tensors against the card's."""
        got = [(t.name, t.shape) for t in (*self.session.get_inputs(), *self.session.get_outputs())]
        want = [(entry.input_name, entry.input_shape), (entry.output_name, entry.output_shape)]
        same = len(got) == 2 and all(
            g[0] == w[0] and len(g[1]) == len(w[1]) and all(
                isinstance(a, str) or a is None if b == "batch" else a == b for a, b in zip(g[1], w[1], strict=True))
            for g, w in zip(got, want, strict=True))
        if not same:
            raise ValueError(f"{path}: its tensors {got} contradict its card's {want}")
        return entry.input_name, entry.output_name

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.session.run([self.output], {self.input: np.ascontiguousarray(x, np.float32)})[0]


def exported_from(stem: str | Path, card: ModelCard) -> dict:
    """What an export of the card's network depends on: the weights' SHA-256 (None where the weights are not
    installed beside the card), its ``symmetry_average`` and ``member_frames``."""
    weights = paths(stem)[0]
    digest = file_sha256(weights) if weights.is_file() else (card.onnx.network.get("weights_sha256")
                                                              if card.onnx else None)
    return {"weights_sha256": digest, "symmetry_average": card.symmetry_average, "member_frames": card.member_frames}


def onnx_values(stem: str | Path, card: ModelCard, device: str = "", threads: int = 1) -> OperatorValues:
    """The card's value source with its network on onnxruntime (ValueError, one line, when the card lists no ONNX
    file or the file contradicts it)."""
    if card.onnx is None:
        raise ValueError(f"{stem}: the model card lists no ONNX export (hjrno export-onnx --model {stem})")
    stale = exported_from(stem, card) != card.onnx.network
    if stale:
        raise ValueError(f"{stem}: the ONNX export predates the card's weights or its symmetry_average / "
                         f"member_frames: re-export it (hjrno export-onnx --model {stem})")
    path = paths(stem)[1].with_name(card.onnx.file)
    return OperatorValues(card, OnnxOperator(path, card.onnx, device, threads), stem, runtime="onnxruntime")
