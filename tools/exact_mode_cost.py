"""Accuracy of the non-leaky (beta = 1) mode, the one a float NIR consumer computes exactly (docs/targets.md §1.4).

For each pair LEAKY:NONLEAKY of checkpoints (the same places and seed, trained with
network.beta = 0.95 and 1): the leaky network as trained, the leaky network deployed with
beta = 1 (recalibrated on the reference traversal, no retraining: the deploy-time option) and the
network trained with beta = 1; W+Prob accuracy (k = 1), R@100P and AUC-PR on the winter queries.

    nice -n 15 python tools/exact_mode_cost.py /tmp/nets/dog_s7.npz:/tmp/nets/if_dog_s7.npz \
        --data ../shared/data/nordland_64x32_summer_winter --threads 1
"""

from __future__ import annotations

import argparse

import torch

from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.io.checkpoint import Checkpoint, load_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.evaluation import calibrate_and_evaluate
from vprsnn_export.threads import set_threads


def wprob_row(ckpt: Checkpoint, beta: float, data: str) -> dict:
    cfg = ckpt.config.replace(**{"network.beta": beta})
    dataset = load_dataset(
        data,
        [*ckpt.reference_traversals, "winter"],
        cfg.preprocess,
        subset=ckpt.data.get("subset"),
        places=ckpt.data.get("places"),
    )
    network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, torch.device("cpu"))
    rows = calibrate_and_evaluate(
        network,
        {t: dataset.traversal(t) for t in ckpt.reference_traversals},
        dataset.place_ids,
        dataset.traversal("winter"),
        dataset.place_ids,
        "winter",
        SequenceOptions(ks=(1,)),
    )
    return next(r for r in rows if r.strategy == "wprob" and r.k == 1).to_dict()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("pairs", nargs="+", help="LEAKY.npz:NONLEAKY.npz")
    parser.add_argument("--data", required=True)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    set_threads(args.threads)
    print("| pair | leaky (beta 0.95) | leaky deployed at beta = 1 | trained at beta = 1 |")
    print("|---|---|---|---|")
    for pair in args.pairs:
        leaky_path, exact_path = pair.split(":")
        leaky, exact = load_checkpoint(leaky_path), load_checkpoint(exact_path)
        cells = [wprob_row(leaky, leaky.config.network.beta, args.data), wprob_row(leaky, 1.0, args.data)]
        cells.append(wprob_row(exact, 1.0, args.data))
        text = [f"{r['accuracy']:.2f} / {r['r_at_100p']:.2f} / {r['auc_pr']:.3f}" for r in cells]
        print(f"| {pair} | " + " | ".join(text) + " |", flush=True)


if __name__ == "__main__":
    main()
