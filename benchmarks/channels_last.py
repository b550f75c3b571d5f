"""Inference cost of the node's stencil: 3 × 3 (9 slices) against 2 × 2 (4), contiguous against
channels-last convolution weights, one torch thread (what brt_node runs with by default).

Median ms of one forward pass of each bundled model on the stencil's batch of 32 × 32 slices, and of
the untrained operators (default configs) on a batch of 4, as stored and with the CNNs' weights
channels-last (:func:`hjrno_ros.value_function.channels_last_cnns`); max |Δ| is the largest output
difference the layout makes, m:

    .venv/bin/python benchmarks/channels_last.py   # → benchmarks/results/channels_last.{md,json}
"""

import copy
import time
from pathlib import Path

import torch
from hjrno_ros.evaluation import median_ms
from hjrno_ros.operators import build_model
from hjrno_ros.operators.cnn import CNN
from hjrno_ros.value_function import channels_last_cnns

from hjrno_ros import benchmarks, checkpoint


def row(name: str, model: torch.nn.Module, batch: int, n: int = 32, channels: int = 4, scale: float = 1.0) -> dict:
    x = torch.randn(batch, channels, n, n, generator=torch.Generator().manual_seed(0))
    fast = copy.deepcopy(model)
    channels_last_cnns(fast)
    with torch.no_grad():
        plain_ms, fast_ms = (median_ms(m, x, repeats=30) for m in (model, fast))
        diff = float((model(x) - fast(x)).abs().max()) * scale
    return {"model": name, "batch": batch, "ms_contiguous": round(plain_ms, 2), "ms_channels_last": round(fast_ms, 2),
            "speed_up": round(plain_ms / fast_ms, 2), "max_abs_diff_m": float(f"{diff:.2g}"),
            "has_cnn": any(isinstance(m, CNN) for m in model.modules())}


def main(stems=("models/v5", "models/default")) -> int:
    torch.set_num_threads(1)
    rows = []
    for stem in stems:
        model, card = checkpoint.load_model(stem)
        for batch in (9, 4):  # 3 × 3 and 2 × 2 (v, θ) stencils
            rows.append(row(stem, model, batch, scale=card["inputs"]["value_scale"]))
            print(rows[-1], flush=True)
    for kind in ("fno", "tno", "cnn"):
        rows.append(row(f"{kind} (untrained, default config)", build_model(kind, in_channels=4).eval(), 4))
        print(rows[-1], flush=True)
    note = (f"`benchmarks/channels_last.py` on {benchmarks.machine()}, {time.strftime('%Y-%m-%d')}, torch threads 1: "
            "median ms of one forward pass on a batch of 32 × 32 slices (9 = the node's former 3 × 3 (v, θ) stencil, "
            "4 = its 2 × 2 stencil); channels_last = the CNNs' weights stored channels-last, which brt_node does on "
            "CPU; max_abs_diff_m = the largest output difference that makes (bundled models in metres).")
    return benchmarks.write_table(Path("benchmarks/results"), "channels_last",
                                  "Stencil size and channels-last weights", rows, note)


if __name__ == "__main__":
    raise SystemExit(main())
