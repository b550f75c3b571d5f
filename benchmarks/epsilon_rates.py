"""Error rates of a model at given margins ε on the fresh halves of held-out test splits: what a card's
ε guarantees on data it was not calibrated on (e.g. the same scenarios solved with ``--inflation``, the
obstacles ``brt_node`` uses by default, the model reading l − r as the node feeds it, or with
``--inflation-at output`` reading l, r off its output).  Rates as in ``hjrno calibrate`` (calibration.error_rates).

    .venv/bin/python benchmarks/epsilon_rates.py --model models/default --epsilon 0,0.1533,0.2426 \\
        --data data/single32_r23,data/two32_r23,data/windows32_r23,data/windows32b_r23,data/indoor32c_r23 \\
        > benchmarks/results/epsilon_rates/v5_inflated_0.23.md
"""

import argparse

from hjrno_ros import calibration, held_out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="models/default", help="model stem")
    parser.add_argument("--data", required=True, help="comma-separated dataset folders")
    parser.add_argument("--epsilon", required=True, help="comma-separated margins, m")
    parser.add_argument("--inflation-at", default="input", choices=held_out.INFLATION_AT,
                        help="the model reads l - r (default, as brt_node) or l with r off its output")
    args = parser.parse_args()
    fresh = held_out.load([f for f in args.data.split(",") if f], "fresh", unconverged=True)
    pred = held_out.predict(args.model, fresh, inflation_at=args.inflation_at)
    truth = [s.value for s in fresh]
    print(f"{args.model} on the fresh halves of {args.data} ({len(fresh)} scenarios, unconverged used, "
          f"inflation at the model's {args.inflation_at})\n")
    print("| ε m | miss P(V_pred > ε \\| V_gt ≤ 0) | false-safe P(V_gt ≤ 0 \\| V_pred > ε) "
          "| conservative P(V_pred ≤ ε \\| V_gt > 0) |")
    print("|---|---|---|---|")
    for eps in (float(e) for e in args.epsilon.split(",")):
        r = calibration.error_rates(pred, truth, eps)
        print(f"| {eps:.4f} | {r['miss_rate']:.2e} | {r['false_safe_rate']:.2e} | {r['conservative_rate']:.4f} |")


if __name__ == "__main__":
    main()
