"""`vprsnn-export quantize`: a float checkpoint -> one fixed-point model per bit width."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..export.model import save_fixed_point
from ..io.checkpoint import checkpoint_sha256, load_checkpoint
from ..io.fileio import check_output
from ._common import (
    add_bits_option,
    add_data_options,
    add_quantise_options,
    add_runtime_options,
    bit_widths,
    format_table,
    print_json,
    quantise_options,
    query_data,
)

if TYPE_CHECKING:
    from ..export.quantize import QuantiseOptions

TABLE_COLUMNS = (
    ("bits", "bits"),
    ("scheme", "scheme"),
    ("scale_method", "scale"),
    ("weight_max_abs_error", "max |w err|"),
    ("weight_relative_rmse", "rel. RMSE"),
    ("weights_clipped", "clipped w"),
    ("threshold_max_relative_error", "max theta err"),
    ("calibration_saturations", "cal. saturations"),
    ("file", "file"),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("quantize", help="quantise a float checkpoint into fixed-point models")
    parser.add_argument("checkpoint", help="checkpoint written by train")
    add_bits_option(parser)
    parser.add_argument("--out", required=True, help="folder for the model files")
    parser.add_argument("--force", action="store_true", help="replace model files that exist in --out")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_quantise_options(parser)
    add_data_options(parser, data_required=False)
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def model_filename(bits: int, options: QuantiseOptions) -> str:
    """e.g. model_8bit_per-neuron_max.npz, model_4bit_per-neuron_mse_folded.npz, model_8bit_per-neuron_max_non-leaky.npz."""
    scheme = "per-neuron" if options.per_neuron else "per-tensor"
    suffix = ("_folded" if options.fold_thresholds else "") + ("_non-leaky" if options.non_leaky else "")
    return f"model_{bits}bit_{scheme}_{options.scale_method}{suffix}.npz"


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..runtime.deployment import check_reference_places, deploy

    widths = bit_widths(args)
    options = quantise_options(args)
    ckpt = load_checkpoint(args.checkpoint)
    digest = checkpoint_sha256(args.checkpoint)
    device = resolve_device(args.device)
    reference_images = None
    if options.calibration == "deployed":
        dataset = query_data(args, ckpt)
        check_reference_places(dataset.place_ids, ckpt.reference_place_ids)
        reference_images = {name: dataset.traversal(name) for name in ckpt.reference_traversals}
    paths = [Path(args.out) / model_filename(bits, options) for bits in widths]
    for path in paths:  # every output is checked before any quantisation runs
        check_output(path, overwrite=args.force)
    rows = []
    for bits, file in zip(widths, paths, strict=True):
        model = deploy(
            ckpt, digest, bits, options, reference_images=reference_images, device=device, progress=not args.quiet
        )
        path = save_fixed_point(file, model)
        report = model.quantisation.to_dict()
        folded = " folded" if report["threshold_folding"] else ""
        scheme = ("per-neuron" if report["per_neuron"] else "per-tensor") + folded
        sat = report["calibration_saturations"]
        rows.append(
            {**report, "scheme": scheme, "calibration_saturations": "-" if sat is None else sat, "file": str(path)}
        )
    if args.json:
        print_json({"checkpoint": str(args.checkpoint), "source_sha256": digest, "models": rows})
    else:
        print(format_table(rows, TABLE_COLUMNS))
        for row in rows:
            per_module = row.get("module_weight_relative_rmse") or []
            if len(per_module) > 1:
                worst = int(np.argmax(per_module))
                print(
                    f"  {row['bits']} bits, {len(per_module)} modules: rel. RMSE per module "
                    f"{min(per_module):.4g} to {max(per_module):.4g} (worst: module {worst}), "
                    f"clipped weights {sum(row['module_weights_clipped'])}"
                )
        if not args.quiet:
            print(f"\nwrote {len(rows)} fixed-point model(s) to {args.out}", file=sys.stderr)
    return 0
