"""`vprsnn-export train`: STDP training plus calibration, written as one checkpoint."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..cluster import CLUSTER_HELP, parse_cluster
from ..config import Config
from ..data.dataset import dataset_files, load_dataset, scoring_truth, selection_record
from ..errors import InvalidValueError
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
    adapt = parser.add_argument_group("adaptation from a second, unlabelled traversal (docs/model.md)")
    adapt.add_argument(
        "--adapt-from",
        metavar="TRAVERSAL",
        help="a second traversal of the route to learn an adaptation from (never used as a reference nor to "
        "calibrate); needs --adapt, since no mechanism lifted recognition on every fold tried "
        "(docs/research/route-recognition.md section 8)",
    )
    adapt.add_argument(
        "--adapt",
        choices=ADAPTATIONS,
        help="what to learn from it: gain (a per-input gain, encoder.input_gain; it lifted cosine on every quarter "
        "of the Nordland dev route and on no half of the LENS example route)",
    )
    adapt.add_argument(
        "--adapt-places",
        metavar="RANGES",
        help="the places whose frames of that traversal it may learn from, START:COUNT ranges joined by commas "
        "(default: every selected place)",
    )
    adapt.add_argument(
        "--adapt-pairing",
        choices=("sequence", "truth"),
        default="sequence",
        help="how its frames are paired with reference places: sequence (matching 10 frames along the diagonal, "
        "no labels) or truth (by place id, for frame-aligned data) (default: %(default)s)",
    )
    add_runtime_options(parser)
    parser.add_argument(
        "--cluster",
        help=f"train the modules on a Ray cluster, one task per module, CPU workers ({CLUSTER_HELP}); "
        "the checkpoint is byte-identical to the single-process one",
    )
    parser.set_defaults(handler=run, output_kind="file")


ADAPTATIONS = ("gain",)  # trainer.adaptation.MECHANISMS, named here so that --help loads no torch (tested)


def check_not_a_frame(out: Path, data: Path, traversals: list[str]) -> None:
    """InvalidValueError when ``--out`` is an image file name or lies inside a traversal folder read."""
    from ..data.frames import IMAGE_SUFFIXES

    inside = [f for name in traversals if (f := data / name).is_dir() and out.resolve().is_relative_to(f.resolve())]
    if out.suffix.lower() in IMAGE_SUFFIXES or inside:
        where = f"inside the traversal folder {inside[0]}" if inside else "an image file name"
        raise InvalidValueError(f"--out {out}: {where}; a checkpoint never replaces a frame of the data set")


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..trainer.adaptation import adapt_config, parse_place_ranges
    from ..trainer.pipeline import train_and_calibrate

    inputs = (args.data, args.subset, Path(args.data) / "places.csv")
    check_output(args.out, overwrite=args.force, inputs=inputs)  # before minutes of training, not after
    cfg = config_from_args(args)
    references = parse_names(args.reference, "--reference")
    if (args.adapt is None) != (args.adapt_from is None) or (args.adapt_places and not args.adapt_from):
        raise InvalidValueError(
            "--adapt-from TRAVERSAL and --adapt MECHANISM go together (no mechanism is a default: none lifted "
            "recognition on every fold tried, docs/research/route-recognition.md section 8); --adapt-places needs both"
        )
    adapt_places = None if args.adapt_places is None else parse_place_ranges(args.adapt_places)
    device = resolve_device(args.device)
    cluster = None if args.cluster is None else parse_cluster(args.cluster, threads=args.threads)
    traversals = references + ([args.adapt_from] if args.adapt_from and args.adapt_from not in references else [])
    check_not_a_frame(Path(args.out), Path(args.data), traversals)
    dataset = load_dataset(
        args.data, traversals, cfg.preprocess, subset=args.subset, places=args.places, progress=not args.quiet
    )
    check_output(args.out, overwrite=args.force, inputs=dataset_files(dataset, args.subset))  # nor a GT file
    started = time.perf_counter()
    record = None
    if args.adapt_from:
        adaptation = adapt_config(
            dataset,
            references,
            args.adapt_from,
            cfg,
            mechanism=args.adapt,
            places=adapt_places,
            pairing=args.adapt_pairing,
            truth=scoring_truth(dataset, references, args.adapt_from) if args.adapt_pairing == "truth" else None,
        )
        cfg, record = adaptation.config, adaptation.summary
    ckpt = train_and_calibrate(
        dataset,
        references,
        cfg,
        device=device,
        progress=not args.quiet,
        selection=selection_record(args.subset, args.places),
        threads=args.threads,
        cluster=cluster,
        adaptation=record,
    )
    path = save_checkpoint(args.out, ckpt)
    if warning := capacity_warning(len(dataset.place_ids), cfg):  # after the run: an error stays the only stderr line
        print(f"warning: {warning}", file=sys.stderr)
    where = device if cluster is None else f"cluster {cluster.address}"
    print(
        f"trained {cfg.train.epochs} epochs on {len(dataset.place_ids)} places x {len(references)} traversal(s) "
        f"in {time.perf_counter() - started:.1f} s on {where} ({args.threads} thread(s)); wrote {path}"
    )
    unadapted = "none (no second traversal named; --adapt-from TRAVERSAL --adapt gain learns one)"
    print(f"adaptation: {unadapted if record is None else record}")
    return 0


def capacity_warning(n_places: int, cfg: Config) -> str | None:
    """A warning when one module must learn more places than it has neurons; the module size it suggests is n / 4."""
    per_module = min(cfg.train.module_size or n_places, n_places)
    neurons = cfg.network.n_neurons
    if per_module <= neurons:
        return None
    return (
        f"{per_module} places per module but {neurons} neurons: the module cannot give every place a neuron of "
        f"its own; train an ensemble with --module-size {max(1, neurons // 4)} (or more --neurons)"
    )
