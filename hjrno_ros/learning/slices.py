"""Operator inputs and targets: 2D x-y slices of (V0, V∞) with constant state/parameter channels.

A slice fixes every state variable but (x, y): the car's (v, θ), Air3D's ψ.  Input channels are
the V0 slice, then constants: normalised v, cos θ, sin θ (car) or cos ψ, sin ψ (Air3D), then the
normalised varying parameters (a_max, κ_max for the parametric family; ``log_a_max``, the logarithm of
a_max/(v_max·ω_top) in model units, for datasets drawn with an ``accel_ratio`` range).  Values are divided by
``value_scale`` (m).  :class:`InputSpec` is stored in the model card, so the node builds exactly
the inputs the model was trained on.

A *table* model (``InputSpec.table`` = (nv, nθ)) predicts the whole (v, θ) table of a ground robot in one
forward pass: its inputs are V0 and the parameters only, its output has one channel per (v, θ) node of the
card's grid, channel iv·nθ + iθ (:class:`TableSet`, :func:`table_symmetry`).
"""

from __future__ import annotations

import numpy as np
import torch

from hjrno_ros.core import model_inputs
from hjrno_ros.core.grids import wrap_angle
from hjrno_ros.core.model_inputs import param_value


class InputSpec(model_inputs.InputSpec):
    """:class:`hjrno_ros.core.model_inputs.InputSpec` with the inputs as a torch tensor."""

    def inputs(self, v0: np.ndarray, v: np.ndarray, angle: np.ndarray, params: np.ndarray | None = None
               ) -> torch.Tensor:
        """:meth:`array` as a tensor."""
        return torch.from_numpy(self.array(v0, v, angle, params))


def spec_for(split, table: bool = False) -> InputSpec:
    """The input spec of a loaded dataset split (family decides the constant channels); ``table``: a model of the
    whole (v, θ) table (a ground robot whose target does not depend on v)."""
    grid, family = split.grid, split.config.family
    scale = 0.5 * max(grid.hi[0] - grid.lo[0], grid.hi[1] - grid.lo[1])
    if family == "air3d":
        if table:
            raise ValueError("a table model is for the ground robots, not Air3D")
        return InputSpec("air3d", scale)
    if table and family in ("velocity", "parametric"):
        raise ValueError(f"a table model needs one target for every speed and fixed limits; the {family} family "
                         "has neither")
    params = {"a_max": (0.5, 1.5), "kappa_max": (0.5, 1.5)} if family == "parametric" else {}
    if split.config.accel_ratio:
        params = {"log_a_max": tuple(float(np.log(r)) for r in split.config.accel_ratio)}
    return InputSpec("car", scale, (grid.lo[2], grid.hi[2]), params, tuple(grid.shape[2:]) if table else None)


def symmetry(images: np.ndarray, theta: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Element ``k`` (0..7) of the square's symmetry group D4 applied per item to x-y slices
    (B, Nx, Ny) and headings θ (B,) in rad: first, if k ≥ 4, the reflection y → −y (θ → −θ), then
    k mod 4 quarter turns (x, y) → (−y, x) about the window centre (θ → θ + π/2 each).

    The car's dynamics commute with these maps (the disturbance is a ball, the curvature bounds
    are symmetric), so a transformed (V0, V∞) slice pair is another exact sample of the same
    family: an 8-fold larger training set at no solving cost.  Needs a square window.
    """
    out = np.empty_like(images)
    for b, kb in enumerate(np.asarray(k)):
        image = images[b, :, ::-1] if kb >= 4 else images[b]
        out[b] = np.rot90(image, kb % 4)
    turned = np.where(np.asarray(k) >= 4, -theta, theta) + (np.asarray(k) % 4) * (np.pi / 2)
    return out, wrap_angle(turned)


def heading_permutation(n: int, k: int) -> np.ndarray:
    """For a periodic heading axis of ``n`` nodes from −π: the node each heading moves to under D4 element ``k``
    (:func:`symmetry`), so ``out[..., perm[j], :, :] = table[..., j, :, :]``.  Needs n divisible by 4."""
    if n % 4:
        raise ValueError(f"the D4 symmetries need a heading count divisible by 4, got {n}")
    step = 2 * np.pi / n
    headings = -np.pi + step * np.arange(n)
    _, turned = symmetry(np.zeros((n, 1, 1), np.float32), headings, np.full(n, k))
    return np.round((turned + np.pi) / step).astype(int) % n


def table_symmetry(tables: np.ndarray, k: np.ndarray) -> np.ndarray:
    """D4 element ``k`` (one per item) applied to whole tables ``(B, nv, nθ, Nx, Ny)``: the x-y images move as in
    :func:`symmetry` and each slice moves to its transformed heading."""
    out = np.empty_like(tables)
    b, nv, nt, nx, ny = tables.shape
    for i, ki in enumerate(np.asarray(k)):
        images = tables[i].reshape(nv * nt, nx, ny)
        moved, _ = symmetry(images, np.zeros(nv * nt), np.full(nv * nt, ki))
        out[i][:, heading_permutation(nt, int(ki))] = moved.reshape(nv, nt, nx, ny)
    return out


class TableSet:
    """All samples of a split as whole-table items for a table model: inputs (V0, parameters), targets
    ``(B, nv·nθ, Nx, Ny)``."""

    def __init__(self, split, spec: InputSpec):
        if spec.table is None or tuple(split.grid.shape[2:]) != spec.table:
            raise ValueError(f"a table set needs a table spec of the split's (v, θ) shape {split.grid.shape[2:]}")
        self.split, self.spec = split, spec
        self.params = np.array([[param_value(s.params, k) for k in spec.param_ranges] for s in split.scenarios],
                               np.float32)

    def __len__(self) -> int:
        return len(self.split.target)

    def check_symmetric(self) -> None:
        """Raise unless :func:`table_symmetry` maps this split's tables onto exact samples."""
        SliceSet.check_symmetric(self)  # type: ignore[arg-type]
        heading_permutation(self.split.grid.shape[3], 1)

    def batch(self, index: np.ndarray, sym: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Inputs and targets of samples ``index``; ``sym`` (one 0..7 per item): apply the D4 element."""
        index = np.asarray(index)
        v0 = np.asarray(self.split.target[index, :, :, 0, 0], np.float32)
        y = np.moveaxis(np.asarray(self.split.value[index], np.float32), (3, 4), (1, 2))
        if sym is not None:
            v0, _ = symmetry(v0, np.zeros(len(index)), sym)
            y = table_symmetry(y, sym)
        params = self.params[index] if self.spec.param_ranges else None
        x = self.spec.inputs(v0, np.zeros(len(index)), np.zeros(len(index)), params)
        b, nv, nt, nx, ny = y.shape
        return x, torch.from_numpy(np.ascontiguousarray(y.reshape(b, nv * nt, nx, ny)) / self.spec.value_scale)


def as_slices(t: torch.Tensor) -> torch.Tensor:
    """``(B, C, Nx, Ny)`` → ``(B·C, 1, Nx, Ny)``: a table model's output scored slice by slice like a slice model's."""
    return t.reshape(-1, 1, *t.shape[2:])


class SliceSet:
    """All (sample, slice) pairs of a split, batched on demand as tensors (x, y)."""

    def __init__(self, split, spec: InputSpec):
        self.split, self.spec = split, spec
        self.angle_axis = 3 if spec.kind == "car" else 2
        self.slice_shape = split.grid.shape[2:]
        self.n_slices = int(np.prod(self.slice_shape))
        self.params = np.array([[param_value(s.params, k) for k in spec.param_ranges] for s in split.scenarios],
                               np.float32)
        self.angles = split.grid.axis(self.angle_axis)
        self.speeds = split.grid.axis(2) if spec.kind == "car" else np.zeros(1)

    def __len__(self) -> int:
        return len(self.split.target) * self.n_slices

    def locate(self, index: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        sample, rest = np.divmod(index, self.n_slices)
        return sample, np.unravel_index(rest, self.slice_shape)

    def angle_neighbour(self, index: np.ndarray) -> np.ndarray:
        """The slice of the same sample and speed at the next grid angle (θ or ψ, periodic)."""
        index = np.asarray(index)
        n_angle = self.slice_shape[-1]
        k = index % n_angle
        return index - k + (k + 1) % n_angle

    def check_symmetric(self) -> None:
        """Raise unless :func:`symmetry` maps this split's slices onto exact samples."""
        lo, hi, shape = self.split.grid.lo, self.split.grid.hi, self.split.grid.shape
        if self.spec.kind != "car":
            raise ValueError("symmetry augmentation is for the car (Air3D's relative frame is not symmetric)")
        if shape[0] != shape[1] or not np.isclose(hi[0] - lo[0], hi[1] - lo[1]):
            raise ValueError(f"symmetry augmentation needs a square x-y window, got {shape[:2]} nodes over "
                             f"{hi[0] - lo[0]:g} m x {hi[1] - lo[1]:g} m")

    def batch(self, index: np.ndarray, sym: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Inputs and targets of slices ``index``; ``sym`` (one 0..7 per item): apply :func:`symmetry`."""
        sample, sl = self.locate(np.asarray(index))
        v0 = self.split.target[(sample, slice(None), slice(None), *sl)]
        y = self.split.value[(sample, slice(None), slice(None), *sl)]
        v = self.speeds[sl[0]] if self.spec.kind == "car" else np.zeros(len(sample))
        angle = self.angles[sl[-1]]
        if sym is not None:
            v0, _ = symmetry(np.asarray(v0, np.float32), angle, sym)
            y, angle = symmetry(np.asarray(y, np.float32), angle, sym)
        params = self.params[sample] if self.spec.param_ranges else None
        x = self.spec.inputs(v0, v, angle, params)
        return x, torch.from_numpy(np.asarray(y, np.float32) / self.spec.value_scale)[:, None]


class SliceUnion:
    """Several slice sets (e.g. datasets of different families on one grid) as one."""

    def __init__(self, parts: list[SliceSet]):
        if not parts:
            raise ValueError("need at least one dataset")
        shapes = {p.split.grid.shape for p in parts}
        if len(shapes) != 1:
            raise ValueError(f"datasets to combine must share one grid, got {sorted(shapes)}")
        self.parts = parts
        self.offsets = np.cumsum([0] + [len(p) for p in parts])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def angle_neighbour(self, index: np.ndarray) -> np.ndarray:
        """:meth:`SliceSet.angle_neighbour` of each slice, within its own dataset: the parts share one
        grid, so every offset is a whole number of angle cycles and one part's rule serves all."""
        return self.parts[0].angle_neighbour(index)

    def batch(self, index: np.ndarray, sym: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        index = np.asarray(index)
        part = np.searchsorted(self.offsets, index, side="right") - 1
        xs, ys, order = [], [], []
        for k in np.unique(part):
            sel = np.flatnonzero(part == k)
            x, y = self.parts[k].batch(index[sel] - self.offsets[k], None if sym is None else np.asarray(sym)[sel])
            xs.append(x)
            ys.append(y)
            order.append(sel)
        inverse = np.argsort(np.concatenate(order))
        return torch.cat(xs)[inverse], torch.cat(ys)[inverse]


def relative_l2(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Mean over the batch of ‖pred − target‖₂ / ‖target‖₂ per item; with ``weight`` (same shape),
    the squared error of each point counts ``weight`` times."""
    dims = tuple(range(1, pred.ndim))
    err = (pred - target) ** 2 if weight is None else weight * (pred - target) ** 2
    return (torch.sqrt(err.sum(dims)) / torch.sqrt((target**2).sum(dims)).clamp_min(1e-8)).mean()


def angle_difference_l2(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Relative L2 of the change between paired slices: the batch's first half holds slices, its
    second half the same slices at the next grid angle (``angle_neighbour``).  The sign of V's
    change with θ picks the safe control's turn, and plain relative L2 on V barely sees it."""
    half = len(pred) // 2
    return relative_l2(pred[half:] - pred[:half], target[half:] - target[:half])


def level_set_weight(target: torch.Tensor, strength: float, width: float) -> torch.Tensor:
    """1 + strength · exp(−(target / width)²): extra weight near the zero level set of V∞, where the
    filter acts (``width`` in the target's units)."""
    return 1.0 + strength * torch.exp(-((target / width) ** 2))
