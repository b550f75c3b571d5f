"""A calibrated safety margin ε for a learned value function (no ROS).

The filter trusts the model where V_pred > ε.  What can go wrong is a *false-safe* state: truly
unsafe (V_gt ≤ 0) but V_pred > ε.  ε is chosen by split conformal prediction on held-out solved
scenarios that the model never saw:

* calibration points are i.i.d. draws of a state the ground-truth filter would act on: a
  scenario uniformly from the calibration scenarios, then a grid state uniformly from
  {V_gt ≤ δ}, where δ ≥ 0 is the margin the ground-truth filter itself needs in sampled-data
  closed loop (measured by ``hjrno simulate``; δ = 0 gives the plain unsafe set);
* the score is V_pred at that state; ε = the k-th smallest of n scores (at least δ), with k the
  smallest integer such that P(Binomial(n, 1 − α) ≥ k) ≤ β (training-conditional conformal,
  Vovk 2012).

Then, with probability ≥ 1 − β over the calibration draw, the miss rate
P(V_pred > ε | V_gt ≤ δ) ≤ α for a fresh draw from the same distribution: the learned filter acts
wherever the ground-truth filter with margin δ would, but for a fraction ≤ α; in particular
P(V_pred > ε | V_gt ≤ 0) ≤ α as well, since {V_gt ≤ 0} ⊂ {V_gt ≤ δ} carries the lower scores.  The conditional the
filter cares about, P(V_gt ≤ 0 | V_pred > ε), is this miss rate times P(unsafe) / P(V_pred > ε),
smaller still; it is estimated (with a Clopper-Pearson upper bound at level β) from uniform draws
over all grid states and written next to ε.  The guarantee is over the calibration scenarios'
distribution; a fresh split of new scenarios measures how well it carries over.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hjrno_ros.core.model_card import ModelCard

DEFAULT_MARGIN = 0.1  # m: δ, what the ground-truth switch filter needed in closed loop (docs/results.md, "Closed loop")


@dataclasses.dataclass(frozen=True)
class Calibration:
    epsilon: float  # m
    margin: float  # δ, m
    alpha: float
    beta: float
    n: int  # calibration draws (unsafe states)
    rank: int  # k: ε is the k-th smallest score
    scenarios: int
    precision_bound: float  # Clopper-Pearson upper bound of P(V_gt ≤ 0 | V_pred > ε) at level β
    precision_estimate: float  # its point estimate

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def conformal_rank(n: int, alpha: float, beta: float) -> int:
    """Smallest k with P(Binomial(n, 1 − α) ≥ k) ≤ β; ValueError if even k = n is not enough."""
    from scipy import stats  # here, not at import: the command line imports this module for its defaults

    if not (0 < alpha < 1 and 0 < beta < 1):
        raise ValueError(f"alpha and beta must lie in (0, 1), got {alpha}, {beta}")
    k = np.arange(1, n + 1)
    ok = stats.binom.sf(k - 1, n, 1 - alpha) <= beta
    if not ok.any():
        need = int(np.ceil(np.log(beta) / np.log(1 - alpha)))
        raise ValueError(f"{n} calibration draws cannot certify alpha={alpha}, beta={beta}; need at least {need}")
    return int(k[ok.argmax()])


def _draw(rng: np.random.Generator, pred: list[np.ndarray], truth: list[np.ndarray], n: int,
          below: float | None) -> tuple[np.ndarray, np.ndarray]:
    """n i.i.d. (V_pred, V_gt) pairs: a scenario uniformly, then a state uniformly (from {V_gt ≤ below})."""
    unsafe_only = below is not None
    pools = [np.flatnonzero(t.ravel() <= below) if unsafe_only else None for t in truth]
    usable = [i for i, pool in enumerate(pools) if pool is None or pool.size]
    if not usable:
        raise ValueError(f"no calibration scenario has a state with V_gt <= {below}")
    which = rng.choice(usable, n)
    p, t = np.empty(n), np.empty(n)
    for i in np.unique(which):
        sel = which == i
        states = (rng.choice(pools[i], sel.sum()) if unsafe_only else rng.integers(0, truth[i].size, sel.sum()))
        p[sel], t[sel] = pred[i].ravel()[states], truth[i].ravel()[states]
    return p, t


def calibrate(pred: list[np.ndarray], truth: list[np.ndarray], alpha: float = 0.01, beta: float = 0.05,
              n: int = 20000, seed: int = 0, margin: float = 0.0) -> Calibration:
    """ε from value tables predicted / solved on the calibration scenarios (one array each)."""
    from scipy import stats

    if not margin >= 0:
        raise ValueError(f"margin must be >= 0, got {margin}")
    rng = np.random.default_rng(seed)
    k = conformal_rank(n, alpha, beta)
    scores, _ = _draw(rng, pred, truth, n, below=margin)
    epsilon = max(float(np.sort(scores)[k - 1]), margin)
    p, t = _draw(rng, pred, truth, n, below=None)
    trusted = p > epsilon
    bad = int((t[trusted] <= 0).sum())
    m = int(trusted.sum())
    bound = float(stats.beta.ppf(1 - beta, bad + 1, m - bad)) if bad < m else 1.0
    return Calibration(epsilon, margin, alpha, beta, n, k, len(pred), bound, bad / max(m, 1))


def error_rates(pred: list[np.ndarray], truth: list[np.ndarray], epsilon: float) -> dict:
    """Rates over all grid states, each scenario weighted equally: miss = P(V_pred > ε | V_gt ≤ 0),
    false_safe = P(V_gt ≤ 0 | V_pred > ε), conservative = P(V_pred ≤ ε | V_gt > 0)."""
    miss, joint, trusted_share, cons = [], [], [], []
    for p, t in zip(pred, truth, strict=True):
        unsafe, trusted = t <= 0, p > epsilon
        if unsafe.any():
            miss.append(np.mean(trusted[unsafe]))
        if (~unsafe).any():
            cons.append(np.mean(~trusted[~unsafe]))
        joint.append(np.mean(unsafe & trusted))
        trusted_share.append(np.mean(trusted))
    mean = lambda a: float(np.mean(a)) if a else float("nan")  # noqa: E731
    false_safe = mean(joint) / mean(trusted_share) if mean(trusted_share) > 0 else 0.0
    return {"epsilon": float(epsilon), "miss_rate": mean(miss), "false_safe_rate": false_safe,
            "conservative_rate": mean(cons)}


def calibrate_model(stem, folders: list, alpha: float, beta: float, n: int, seed: int = 0,
                    margin: float = DEFAULT_MARGIN, write: bool = True, unconverged: bool = False,
                    average: bool | None = None, frames: list | None = None, refine: float = 0.0) -> dict:
    """Calibrate ε on the first half of the test splits, measure on the second, write it into the card
    (``unconverged``: also use scenarios whose solve missed the tolerance; recorded in the card).
    ``average`` (None: the card's setting) calibrates the symmetry-averaged model or the plain one and
    records that choice in the card with ε, since ε only holds for the predictions it was measured on;
    ``frames`` (None: the card's) likewise for an ensemble's member frames (checkpoint.framed_members).
    ``refine`` > 0 calibrates the model's tables after that many simulated s of the solver warm-started from
    them (brt_node's refine_horizon) instead, and writes ``refine_epsilon`` and ``refine_calibration``:
    the card's ε, for the operator alone, stays as it is."""
    from hjrno_ros.learning import checkpoint
    from hjrno_ros.learning.onnx_export import refresh_export
    from hjrno_ros.studies import held_out

    if not (np.isfinite(refine) and refine >= 0):
        raise ValueError(f"refine must be finite and >= 0 (simulated s), got {refine}")
    card = ModelCard.load(stem)
    calib, fresh = (held_out.load(folders, part, unconverged) for part in ("calibration", "fresh"))
    averaged = card.symmetry_average if average is None else bool(average)
    frames = card.member_frames if frames is None else frames
    if refine > 0 and write and (averaged, frames or None) != (card.symmetry_average, card.member_frames):
        raise ValueError("calibrating refined tables writes no model settings: leave --symmetry-average and "
                         "--member-frames at the card's")
    pred = held_out.predict(stem, calib + fresh, averaged, frames=frames or [])  # [] = none, not the card's
    if refine > 0:
        pred = held_out.refine(calib + fresh, pred, refine)
    result = calibrate(pred[:len(calib)], [s.value for s in calib], alpha, beta, n, seed, margin)
    pred_fresh, truth_fresh = pred[len(calib):], [s.value for s in fresh]
    entry = {**result.as_dict(), "seed": seed, "data": [str(f) for f in folders], "unconverged_allowed": unconverged,
             "symmetry_average": averaged, "member_frames": frames or None,
             "calibration_scenarios": [s.name for s in calib], "fresh_scenarios": [s.name for s in fresh],
             "fresh_before": error_rates(pred_fresh, truth_fresh, 0.0),
             "fresh_after": error_rates(pred_fresh, truth_fresh, result.epsilon)}
    if refine > 0:
        entry["horizon_s"] = float(refine)
        if write:
            checkpoint.update_card(stem, {"refine_epsilon": result.epsilon, "refine_calibration": entry})
    elif write:
        checkpoint.update_card(stem, {"epsilon": result.epsilon, "symmetry_average": averaged,
                                      "member_frames": frames or None, "calibration": entry})
        refresh_export(stem)  # the ONNX export follows the card's symmetry averaging and member frames
    return entry
