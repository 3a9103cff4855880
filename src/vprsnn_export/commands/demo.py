"""`vprsnn-export demo`: the main job on the embedded synthetic route, no download needed."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ..checkpoint import save_checkpoint
from ..config import Config
from ..dataset import load_dataset
from ..device import resolve_device
from ..fileio import atomic_write_text
from ._common import RESULT_COLUMNS, add_runtime_options, format_table

DEMO_DATA = "synthetic"
DEMO_REFERENCE = "summer"
DEMO_QUERY = "winter"
DEMO_KS = (1, 3, 5)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("demo", help="train and evaluate on the embedded synthetic route")
    parser.add_argument("--out", default="vprsnn-demo", help="output folder (default: ./vprsnn-demo)")
    parser.add_argument("--seed", type=int, default=Config().seed, help="seed")
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def demo_config(seed: int) -> Config:
    """The paper's configuration; only the seed is chosen here."""
    return Config().replace(seed=seed)


def run(args: argparse.Namespace) -> int:
    from ..runtime.evaluation import ReadoutOptions, evaluate_float
    from ..trainer.pipeline import train_and_calibrate

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = demo_config(args.seed)
    device = resolve_device(args.device)
    progress = not args.quiet
    started = time.perf_counter()
    dataset = load_dataset(DEMO_DATA, [DEMO_REFERENCE, DEMO_QUERY], cfg.preprocess, progress=progress)
    say = (lambda msg: print(msg, file=sys.stderr)) if progress else (lambda msg: None)
    say(f"[demo] synthetic route: {len(dataset.place_ids)} places, reference {DEMO_REFERENCE}, query {DEMO_QUERY}")
    ckpt = train_and_calibrate(dataset, [DEMO_REFERENCE], cfg, device=device, progress=progress,
                               selection={"subset": None, "places": None})
    ckpt_path = save_checkpoint(out / "float.npz", ckpt)
    say(f"[demo] trained {cfg.train.epochs} epochs in {time.perf_counter() - started:.1f} s -> {ckpt_path}")
    options = ReadoutOptions(gamma=cfg.assignment.gamma, ks=DEMO_KS)
    result = evaluate_float(
        ckpt, dataset.traversal(DEMO_QUERY), dataset.place_ids, DEMO_QUERY, options, device=device,
        reference_images={DEMO_REFERENCE: dataset.traversal(DEMO_REFERENCE)},
    )
    payload = {"config": cfg.to_dict(), "results": result["rows"], "spike_stats": result["spike_stats"]}
    atomic_write_text(out / "evaluation.json", json.dumps(payload, indent=2))
    print(format_table(result["rows"], RESULT_COLUMNS))
    print(f"\nwrote {out / 'evaluation.json'} in {time.perf_counter() - started:.1f} s")
    return 0
