"""The paired verdict's false-alarm rate (issue 32): the float network judged against itself.

The "deployed" side is the same float network on query spikes drawn with another encoder seed, so
every difference is sampling noise and a "fails" verdict is a false alarm. For each encoder seed
s in SEEDS the float readout on the checkpoint's own query spikes (seed = config.seed) and the one
on seed s are judged (``--pairs``: seed s against seed s + N, N independent pairs, each with its own base) exactly as `verify` judges a bit width (runtime/verify/paired.py: the default
tolerances, the VerifyConfig statistics); the point checks (tolerance_checks on the point
differences, what `verify` judged before) are counted beside it. Run from the repository root:

    OMP_NUM_THREADS=1 python tools/false_alarm.py NET.npz --query winter --seeds 1:40 [--pairs] [--k 1,3,5]

NET's data source and place selection are used (its checkpoint records them). Prints one row per
seed and the rates; exit 0.
"""

from __future__ import annotations

import argparse
from collections import Counter

import torch

from vprsnn_export.config import VerifyConfig
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.io.checkpoint import load_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.results import worst_verdict
from vprsnn_export.runtime.verify.checks import DEFAULT_TOLERANCES, metric_deltas
from vprsnn_export.runtime.verify.paired import PAIRED_TOLERANCES, judged_limits, paired_checks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--query", required=True)
    parser.add_argument("--seeds", default="1:20", help="encoder seeds FIRST:LAST (inclusive)")
    parser.add_argument("--k", default="1,3,5")
    parser.add_argument("--pairs", action="store_true", help="judge seed s against seed s + N (own base each)")
    args = parser.parse_args()
    first, last = (int(v) for v in args.seeds.split(":"))
    ckpt = load_checkpoint(args.checkpoint)
    cfg = ckpt.config
    data = load_dataset(
        ckpt.data["source"],
        [args.query],
        cfg.preprocess,
        subset=ckpt.data.get("subset"),
        places=ckpt.data.get("places"),
    )
    ids = data.place_ids
    images = data.traversal(args.query)
    readout = SequenceOptions(ks=tuple(int(k) for k in args.k.split(",")))
    scorer = Readout.of(ckpt.calibration, cfg, readout)
    network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, torch.device("cpu"))
    settings = VerifyConfig()
    sequences = readout.warning(ids) is None
    limits = judged_limits(DEFAULT_TOLERANCES, readout.ks, len(ids), sequences=sequences)

    def readout_of(seed: int):
        counts = network.run(query_spikes(images, ids, args.query, cfg.replace(seed=seed))).counts.numpy()
        scored = scorer.score(counts, ckpt.reference_place_ids, ids)
        return scored.rows, scored.decisions()

    base = readout_of(cfg.seed)
    n_seeds = last - first + 1
    base_text = f"seed s + {n_seeds} against seed s" if args.pairs else f"base encoder seed {cfg.seed}"
    print(f"checkpoint {args.checkpoint}: {len(ids)} queries, {base_text}, judged k: "
          f"{sorted({k for _, _, k in limits})}, statistics {settings}")  # fmt: skip
    print("seed  verdict    point-check fails  acc Std / Wt / W+P k=1 Δ (pts)  R@100P k=1 Δ  failing paired checks")
    verdicts: Counter[str] = Counter()
    point_fails = 0
    for seed in range(first, last + 1):
        if seed == cfg.seed and not args.pairs:
            continue
        base_rows, base_decisions = readout_of(seed) if args.pairs else base
        rows, decisions = readout_of(seed + n_seeds if args.pairs else seed)
        rows = metric_deltas(base_rows, rows)
        table = paired_checks(base_decisions, decisions, rows, limits, settings)
        verdict = worst_verdict(c.verdict for c in table if c.verdict in ("holds", "fails", "undecided"))
        verdicts[verdict] += 1
        points = [
            (metric, s, k)
            for (metric, s, k), limit in limits.items()
            if metric in PAIRED_TOLERANCES
            and -next(r for r in rows if (r.strategy, r.k) == (s, k)).delta.get(metric) > limit + 1e-12
        ]
        point_fails += bool(points)
        acc = " / ".join(f"{100 * r.delta.get('accuracy'):+.0f}" for r in rows if r.k == 1)
        r100 = next(r for r in rows if (r.strategy, r.k) == ("wprob", 1)).delta.get("r_at_100p")
        failing = ", ".join(f"{c.metric} {c.strategy} k={c.k}" for c in table if c.verdict == "fails") or "-"
        print(f"{seed:4d}  {verdict:9s}  {'yes' if points else 'no':17s}  {acc:30s}  {100 * r100:+11.0f}  {failing}")
    n = sum(verdicts.values())
    print(
        f"\n{n} seeds: fails {verdicts['fails']} ({100 * verdicts['fails'] / n:.1f} %), undecided "
        f"{verdicts['undecided']} ({100 * verdicts['undecided'] / n:.1f} %), holds {verdicts['holds']} "
        f"({100 * verdicts['holds'] / n:.1f} %); point checks (the previous verdict) fail {point_fails} "
        f"({100 * point_fails / n:.1f} %)"
    )
    float_acc = {r.strategy: r.values.accuracy for r in base[0] if r.k == 1}
    print(
        f"float network (encoder seed {cfg.seed}): " + ", ".join(f"{s} {100 * v:.1f} %" for s, v in float_acc.items())
    )


if __name__ == "__main__":
    main()
