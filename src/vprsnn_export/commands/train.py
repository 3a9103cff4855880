"""`vprsnn-export train`: STDP training plus calibration, written as one checkpoint."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..cluster import CLUSTER_HELP, parse_cluster
from ..config import Config
from ..data.dataset import dataset_files, load_dataset, selection_record
from ..io.checkpoint import save_checkpoint
from ..io.fileio import check_output
from ._common import add_config_options, add_data_options, add_runtime_options, config_from_args, parse_names


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("train", help="train a network with STDP and calibrate it")
    add_data_options(parser, data_required=True)
    parser.add_argument("--reference", required=True, help="reference traversal(s), e.g. summer or spring,fall")
    parser.add_argument("--out", required=True, help="checkpoint file to write (.npz)")
    parser.add_argument("--force", action="store_true", help="replace --out if it exists")
    add_config_options(parser)
    add_runtime_options(parser)
    parser.add_argument(
        "--cluster",
        help=f"train the modules on a Ray cluster, one task per module, CPU workers ({CLUSTER_HELP}); "
        "the checkpoint is byte-identical to the single-process one",
    )
    parser.set_defaults(handler=run, output_kind="file")


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..trainer.pipeline import train_and_calibrate

    inputs = (args.data, args.subset, Path(args.data) / "places.csv")
    check_output(args.out, overwrite=args.force, inputs=inputs)  # before minutes of training, not after
    cfg = config_from_args(args)
    references = parse_names(args.reference, "--reference")
    device = resolve_device(args.device)
    cluster = None if args.cluster is None else parse_cluster(args.cluster, threads=args.threads)
    dataset = load_dataset(
        args.data, references, cfg.preprocess, subset=args.subset, places=args.places, progress=not args.quiet
    )
    check_output(args.out, overwrite=args.force, inputs=dataset_files(dataset, args.subset))  # nor a GT file
    started = time.perf_counter()
    ckpt = train_and_calibrate(
        dataset,
        references,
        cfg,
        device=device,
        progress=not args.quiet,
        selection=selection_record(args.subset, args.places),
        threads=args.threads,
        cluster=cluster,
    )
    path = save_checkpoint(args.out, ckpt)
    warning = capacity_warning(len(dataset.place_ids), cfg)  # after the run: an error stays the only stderr line
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    where = device if cluster is None else f"cluster {cluster.address}"
    print(
        f"trained {cfg.train.epochs} epochs on {len(dataset.place_ids)} places x {len(references)} traversal(s) "
        f"in {time.perf_counter() - started:.1f} s on {where} ({args.threads} thread(s)); wrote {path}"
    )
    return 0


def capacity_warning(n_places: int, cfg: Config) -> str | None:
    """A warning when one module must learn more places than it has neurons (places per module P, or every
    place without modules, above ``network.n_neurons``): some places then have no neuron of their own. The
    suggested module size is n / 4 places (docs/experiments.md: 100 places per module of 400 neurons)."""
    per_module = min(cfg.train.module_size or n_places, n_places)
    neurons = cfg.network.n_neurons
    if per_module <= neurons:
        return None
    suggested = max(1, neurons // 4)
    return (
        f"{per_module} places per module but {neurons} neurons: the module cannot give every place a neuron of "
        f"its own; train an ensemble with --module-size {suggested} (or more --neurons)"
    )
