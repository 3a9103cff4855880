"""Deployed accuracy per bit width beside float: the table of docs/fixed-point.md, reproducibly.

    python bench/quantisation_table.py --out /tmp/q [--seeds 1,2,3,4,5] [--bits 8,6,4,3,2] [--schemes ...]

For every seed it runs exactly these commands (and reuses any file already written):

    vprsnn-export train --data DATA/places.csv --subset DATA/subset_100_places.csv \\
        --reference summer --seed S --out OUT/seedS.npz --quiet
    vprsnn-export evaluate OUT/seedS.npz --query winter --k 1,5 --json --quiet
    vprsnn-export quantize OUT/seedS.npz --bits 8,6,4,3,2 SCHEME_FLAGS --out OUT/seedS_models --force --json --quiet
    vprsnn-export simulate OUT/seedS_models/model_<b>bit_<scheme>.npz --query winter --k 1,5 \\
        --json --quiet --compare OUT/seedS.npz

with SCHEME_FLAGS "--per-tensor" (per-tensor, max) and "--per-neuron" (per-neuron, max) by default;
--schemes also offers per-tensor-mse, per-neuron-mse ("--per-neuron --scale mse") and the
threshold-folded per-neuron-max-folded / per-neuron-mse-folded ("... --fold-thresholds").
It prints W+Prob accuracy and R@100P at k=1 and k=5 as mean +- std over the seeds
(deployed calibration, and the float calibration reused), plus saturations and the
fraction of steps on which the integer network emits exactly the float network's spikes.
All raw JSON goes to OUT/quantisation_results_<schemes>.json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[1].parent / "shared/data/nordland_64x32_summer_winter"
SCHEMES = {
    "per-tensor": ["--per-tensor"],
    "per-neuron": ["--per-neuron"],
    "per-tensor-mse": ["--per-tensor", "--scale", "mse"],
    "per-neuron-mse": ["--per-neuron", "--scale", "mse"],
    "per-neuron-max-folded": ["--per-neuron", "--fold-thresholds"],
    "per-neuron-mse-folded": ["--per-neuron", "--scale", "mse", "--fold-thresholds"],
}
METRICS = (("accuracy", 1), ("r_at_100p", 1), ("accuracy", 5), ("r_at_100p", 5))


def cli(*args: str) -> str:
    """Run one vprsnn-export command; its stdout, or exit with its stderr."""
    done = subprocess.run([sys.executable, "-m", "vprsnn_export.cli", *args], capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"vprsnn-export {' '.join(args)} failed:\n{done.stderr}")
    return done.stdout


def wprob(rows: list[dict], calibration: str | None = None) -> dict[tuple[str, int], float]:
    """The W+Prob metrics of one result, keyed (metric, k); float rows carry no calibration key."""
    found = {}
    for row in rows:
        if row["strategy"] == "wprob" and row.get("calibration") == calibration:
            found.update({(metric, k): row[metric] for metric, k in METRICS if row["k"] == k})
    return found


def seed_results(seed: int, out: Path, bits: str, schemes: list[str]) -> dict:
    ckpt = out / f"seed{seed}.npz"
    if not ckpt.is_file():
        cli(
            "train",
            "--data",
            str(DATA / "places.csv"),
            "--subset",
            str(DATA / "subset_100_places.csv"),
            "--reference",
            "summer",
            "--seed",
            str(seed),
            "--out",
            str(ckpt),
            "--quiet",
        )
    result = {"float": json.loads(cli("evaluate", str(ckpt), "--query", "winter", "--k", "1,5", "--json", "--quiet"))}
    models = out / f"seed{seed}_models"
    for scheme in schemes:
        quantised = json.loads(
            cli(
                "quantize",
                str(ckpt),
                "--bits",
                bits,
                *SCHEMES[scheme],
                "--out",
                str(models),
                "--force",
                "--json",
                "--quiet",
            )
        )
        for entry in quantised["models"]:
            result[f"{entry['bits']}bit {scheme}"] = json.loads(
                cli(
                    "simulate",
                    entry["file"],
                    "--query",
                    "winter",
                    "--k",
                    "1,5",
                    "--json",
                    "--quiet",
                    "--compare",
                    str(ckpt),
                )
            )
    return result


def summary(values: list[float]) -> str:
    return f"{100 * np.mean(values):.1f} ± {100 * np.std(values):.1f}"


def table(results: dict[int, dict], bits: list[int], schemes: list[str]) -> str:
    head = (
        "| network | calibration | acc k=1 | R@100P k=1 | acc k=5 | R@100P k=5 | saturations | same spikes as float |\n"
        "|---|---|---|---|---|---|---|---|"
    )
    lines = [head]
    seeds = sorted(results)
    floats = [wprob(results[s]["float"]["results"]) for s in seeds]
    lines.append("| float | float | " + " | ".join(summary([f[m] for f in floats]) for m in METRICS) + " | - | - |")
    for scheme in schemes:
        for b in bits:
            runs = [results[s][f"{b}bit {scheme}"] for s in seeds]
            saturations = sum(r["saturations"] for r in runs)
            agreement = summary([r["winner_agreement"]["all_steps"] for r in runs])
            for calibration in ("deployed", "float"):
                metrics = [wprob(r["results"], calibration) for r in runs]
                cells = " | ".join(summary([m[key] for m in metrics]) for key in METRICS)
                lines.append(f"| {b}-bit {scheme} | {calibration} | {cells} | {saturations} | {agreement} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="folder for checkpoints, models and the raw JSON")
    parser.add_argument("--seeds", default="1,2,3,4,5")
    parser.add_argument("--bits", default="8,6,4,3,2")
    parser.add_argument("--schemes", default="per-tensor,per-neuron", help=f"from {', '.join(SCHEMES)}")
    args = parser.parse_args()
    schemes = [s for s in args.schemes.split(",") if s]
    unknown = set(schemes) - set(SCHEMES)
    if unknown:
        parser.error(f"unknown schemes {sorted(unknown)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for seed in (int(s) for s in args.seeds.split(",")):
        results[seed] = seed_results(seed, out, args.bits, schemes)
        print(f"seed {seed} done", file=sys.stderr)
    (out / f"quantisation_results_{'+'.join(schemes)}.json").write_text(json.dumps(results, indent=1))
    cfg = next(iter(results.values()))["float"]["config"]
    print(f"T={cfg['encoder']['timesteps']}, epochs={cfg['train']['epochs']}, seeds {args.seeds}, W+Prob, mean ± std\n")
    print(table(results, [int(b) for b in args.bits.split(",")], schemes))


if __name__ == "__main__":
    main()
