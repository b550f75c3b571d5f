"""Error rates of a model at given margins ε on the fresh halves of held-out test splits: what a card's
ε guarantees on data it was not calibrated on (e.g. the same scenarios solved with ``--inflation``, which
is what ``brt_node`` feeds the model by default).  Rates as in ``hjrno calibrate`` (calibration.error_rates).

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
    args = parser.parse_args()
    fresh = held_out.load([f for f in args.data.split(",") if f], "fresh", unconverged=True)
    pred = held_out.predict(args.model, fresh)
    truth = [s.value for s in fresh]
    print(f"{args.model} on the fresh halves of {args.data} ({len(fresh)} scenarios, unconverged used)\n")
    print("| ε m | miss P(V_pred > ε \\| V_gt ≤ 0) | false-safe P(V_gt ≤ 0 \\| V_pred > ε) "
          "| conservative P(V_pred ≤ ε \\| V_gt > 0) |")
    print("|---|---|---|---|")
    for eps in (float(e) for e in args.epsilon.split(",")):
        r = calibration.error_rates(pred, truth, eps)
        print(f"| {eps:.4f} | {r['miss_rate']:.2e} | {r['false_safe_rate']:.2e} | {r['conservative_rate']:.4f} |")


if __name__ == "__main__":
    main()
