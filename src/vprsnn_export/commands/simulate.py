"""`vprsnn-export simulate`: a fixed-point model on the bit-exact integer simulator, read out like `evaluate`."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

import numpy as np

from ..checkpoint import checkpoint_sha256, load_checkpoint
from ..device import resolve_device
from ..errors import InvalidValueError
from ._common import RESULT_COLUMNS, add_query_options, add_runtime_options, format_table, print_json
from .evaluate import load_query_data, readout_options

if TYPE_CHECKING:
    import torch

CALIBRATIONS = ("deployed", "float")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("simulate", help="run a fixed-point model on the integer simulator")
    parser.add_argument("model", help="fixed-point model written by quantize")
    add_query_options(parser)
    parser.add_argument(
        "--compare",
        metavar="CHECKPOINT",
        help="the float source checkpoint: also report how often the integer network picks the float network's winner",
    )
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def evaluate_fixed_point(
    model,
    query_images: np.ndarray,
    query_place_ids: np.ndarray,
    traversal: str,
    options,
    *,
    device: torch.device,
    state_isolation: bool | None = None,
    float_checkpoint=None,
) -> dict:
    """Result rows for both calibrations (deployed S^R and float S^R), spike statistics, saturations.

    With ``float_checkpoint`` the float network runs on the same spike trains and the
    per-step agreement of the two rasters is added as ``winner_agreement``.
    """
    from ..dynamics import FloatNetwork
    from ..encoding import query_spikes
    from ..runtime.evaluation import readout_rows, spike_statistics
    from ..targets.intsim import IntegerNetwork, step_agreement

    spikes = query_spikes(query_images, query_place_ids, traversal, model.config)
    compare = float_checkpoint is not None
    run = IntegerNetwork(model, device).run(spikes, record=compare, state_isolation=state_isolation)
    counts = run.counts.numpy()
    rows = []
    for name, calibration in zip(CALIBRATIONS, (model.calibration, model.float_calibration)):
        for row in readout_rows(calibration, counts, model.reference_place_ids, query_place_ids, options):
            rows.append({"calibration": name, **row})
    result = {
        "rows": rows,
        "spike_stats": spike_statistics(run.candidates_per_step.numpy(), counts),
        "saturations": run.saturations,
        "max_current": run.max_current,
        "query_counts": counts,
    }
    if compare:
        network = FloatNetwork.from_arrays(float_checkpoint.weights, float_checkpoint.thresholds, model.config, device)
        float_run = network.run(spikes, record=True, state_isolation=state_isolation)
        result["winner_agreement"] = step_agreement(float_run.raster, run.raster)
    return result


def run(args: argparse.Namespace) -> int:
    from ..export.model import load_fixed_point

    model = load_fixed_point(args.model)
    float_checkpoint = None
    if args.compare:
        if checkpoint_sha256(args.compare) != model.source_sha256:
            raise InvalidValueError(
                f"--compare {args.compare}: not the checkpoint this model was quantised from (sha256 differs)"
            )
        float_checkpoint = load_checkpoint(args.compare)
    options = readout_options(args, model.config.assignment.gamma)
    dataset = load_query_data(args, model, [args.query])
    result = evaluate_fixed_point(
        model,
        dataset.traversal(args.query),
        dataset.place_ids,
        args.query,
        options,
        device=resolve_device(args.device),
        state_isolation=False if args.no_state_isolation else None,
        float_checkpoint=float_checkpoint,
    )
    if args.json:
        payload = {
            "config": model.config.to_dict(),
            "model": str(args.model),
            "source_sha256": model.source_sha256,
            "query": args.query,
            "bits": model.bits,
            "quantisation": model.quantisation.to_dict(),
            "saturations": result["saturations"],
            "max_current": result["max_current"],
            "results": result["rows"],
            "spike_stats": result["spike_stats"],
        }
        if "winner_agreement" in result:
            payload["winner_agreement"] = result["winner_agreement"]
        print_json(payload)
    else:
        print(format_table(result["rows"], (("calibration", "calibration"), *RESULT_COLUMNS)))
        stats = result["spike_stats"]
        print(
            f"\n{model.bits}-bit model; saturation events: {result['saturations']}; threshold candidates per step: "
            f"{stats['mean_candidates_per_step']:.1f} on average, {100 * stats['multi_candidate_step_fraction']:.1f} % "
            "of steps have more than one",
            file=sys.stderr,
        )
        if "winner_agreement" in result:
            agreement = result["winner_agreement"]
            print(
                f"same spikes as the float network on {100 * agreement['all_steps']:.2f} % of steps "
                f"({100 * agreement['active_steps']:.2f} % of the steps where either spikes)",
                file=sys.stderr,
            )
    return 0
