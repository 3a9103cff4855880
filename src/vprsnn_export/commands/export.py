"""`vprsnn-export export`: write NIR, a Loihi-style description and ONNX, and say what each consumer computes.

MODEL is a float checkpoint (``train``) or a fixed-point model (``quantize``), told apart
by the ``format`` field of its container. NIR takes either. The Loihi description and
ONNX are integer targets: they need a fixed-point model, so a float checkpoint is refused
with the command to run, unless ``--quantize BITS`` asks for an on-the-fly quantisation
(per-neuron max-abs scales, float calibration kept; ``quantize`` offers every other choice).

With ``--check`` every written file is read back and run beside the project's own
simulators, on real query presentations (``--query`` and the data options) or on
synthetic spike trains; the table states exact identities and measured agreements.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..checkpoint import FORMAT as CHECKPOINT_FORMAT
from ..checkpoint import Checkpoint, load_checkpoint
from ..errors import InvalidValueError, ModelFileError
from ..fileio import atomic_write_text, read_container, sha256_file
from ..targets.nir_target import WTA_INHIBITION
from ._common import add_data_options, add_runtime_options, format_table, print_json

TARGETS = ("nir", "loihi", "onnx")
INTEGER_TARGETS = ("loihi", "onnx")
NIR_NAME = "model.nir"
ONNX_NAME = "model.onnx"
LOIHI_DIR = "loihi"
MANIFEST_NAME = "export.json"
CHECK_COLUMNS = (("target", "target"), ("check", "check"), ("result", "result"), ("detail", "detail"))


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("export", help="export a model to NIR, a Loihi-style description and ONNX")
    parser.add_argument("model", help="float checkpoint (train) or fixed-point model (quantize)")
    parser.add_argument("--to", default="nir,loihi,onnx", help="comma-separated targets: nir, loihi, onnx")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument(
        "--quantize",
        type=int,
        metavar="BITS",
        help="float checkpoint only: quantise on the fly for loihi/onnx (per-neuron max-abs scales, float calibration)",
    )
    parser.add_argument(
        "--nir-inhibition",
        type=float,
        default=WTA_INHIBITION,
        help="strength k of the NIR graph's recurrent inhibitory WTA Linear, W[j, i] = -k theta_j "
        f"(default {WTA_INHIBITION}; 0 = a consumer computes the WTA-off network)",
    )
    parser.add_argument(
        "--nir-no-wta-node",
        action="store_true",
        help="leave the recurrent WTA Linear out of the NIR graph (snnTorch and Norse mishandle recurrent graphs)",
    )
    parser.add_argument(
        "--check", action="store_true", help="read every file back and run it beside the project's simulators"
    )
    parser.add_argument(
        "--nir-consumer",
        choices=("nirtorch", "snntorch", "norse"),
        default="nirtorch",
        help="with --check: the metadata-blind NIR consumer to measure (norse: optional package)",
    )
    parser.add_argument("--query", help="with --check: query traversal to present (default: synthetic spike trains)")
    parser.add_argument(
        "--check-samples", type=int, default=16, help="with --check: presentations to run (0 = all queries)"
    )
    add_data_options(parser, data_required=False)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def parse_targets(raw: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(v.strip().lower() for v in raw.split(",") if v.strip()))
    unknown = [n for n in names if n not in TARGETS]
    if not names or unknown:
        raise InvalidValueError(f"--to expects some of {', '.join(TARGETS)}, got {raw!r}")
    return names


def load_model(path: str | Path):
    """A Checkpoint or a FixedPointModel, chosen by the container's ``format`` field."""
    from ..export.model import FORMAT as FIXED_FORMAT
    from ..export.model import load_fixed_point

    meta, _ = read_container(path, "model")
    kind = meta.get("format")
    if kind == CHECKPOINT_FORMAT:
        return load_checkpoint(path)
    if kind == FIXED_FORMAT:
        return load_fixed_point(path)
    raise ModelFileError(f"neither a checkpoint nor a fixed-point model (format {kind!r})", path)


def integer_model(source, bits: int | None, digest: str, targets: tuple[str, ...]):
    """The fixed-point model the integer targets get, or None when none is asked for."""
    from ..export.model import FixedPointModel, check_bits
    from ..export.quantize import quantize_checkpoint

    if isinstance(source, FixedPointModel):
        if bits is not None:
            raise InvalidValueError("--quantize applies to float checkpoints; this is already a fixed-point model")
        return source
    wanted = [t for t in targets if t in INTEGER_TARGETS]
    if not wanted:
        return None
    if bits is None:
        raise InvalidValueError(
            f"{' and '.join(wanted)} need a fixed-point model: run `vprsnn-export quantize CHECKPOINT --bits 8 "
            "--per-neuron --out DIR` and export the model it writes, add --quantize 8 here, or export with --to nir"
        )
    return quantize_checkpoint(source, digest, check_bits(bits), per_neuron=True, scale_method="max")


def consumer_statements(source, model, targets: tuple[str, ...], wta_node: bool, inhibition: float) -> dict[str, str]:
    """What each consumer of each written file computes, in one sentence or three."""
    fixed = not isinstance(source, Checkpoint)
    thresholds = source.threshold if fixed else source.thresholds
    uniform = bool(np.all(thresholds == thresholds[0]))
    notes: dict[str, str] = {}
    if "nir" in targets:
        arithmetic = (
            "float arithmetic on integer mantissas (no round-toward-zero decay, no 24-bit saturation)"
            if fixed
            else "the float network's own arithmetic"
        )
        inhibit = (
            f"plus lateral inhibition ({inhibition} of its threshold per other spike, one step later)"
            if wta_node and inhibition > 0
            else "with no inhibition"
        )
        notes["nir"] = (
            "vprsnn-export's read_nir rebuilds the network exactly (WTA from the metadata). A consumer that reads "
            f"only the nodes (nirtorch with NIR's LIF, snnTorch, Norse) computes {arithmetic}, every neuron over "
            f"threshold spiking (no WTA) {inhibit}. At dt = 1e-4 s Euler gives "
            "v <- beta v + I; Norse ignores r (input scaled by 1 - beta); snnTorch's importer needs one threshold "
            f"for all neurons ({'met' if uniform else 'not met by this model'})"
            + (
                ""
                if not wta_node
                else "; snnTorch's importer starves a LIF with a recurrent Linear and Norse returns "
                "the wta node's output instead of the spikes (--nir-no-wta-node avoids both)"
            )
            + "."
        )
    if "onnx" in targets and model is not None:
        notes["onnx"] = (
            "onnxruntime computes the integer network exactly: spike counts, saturations and the W+Prob "
            "distribution, identical to the integer simulator."
        )
    if "loihi" in targets and model is not None:
        notes["loihi"] = (
            "Lava's bit-accurate Dense + LIF (fixed_pt) compute the candidate raster bit for bit (WTA off) while "
            "a_j < 2**17; the hard WTA is a rule in network.json that a Lava user adds after the LIF population."
        )
    return notes


def export_all(
    source, model, targets: tuple[str, ...], out: Path, digest: str, inhibition: float, wta_node: bool
) -> dict[str, list[Path]]:
    from ..targets.loihi_target import write_loihi
    from ..targets.nir_target import write_nir
    from ..targets.onnx_target import write_onnx

    written: dict[str, list[Path]] = {}
    if "nir" in targets:
        written["nir"] = [
            write_nir(source, out / NIR_NAME, source_sha256=digest, wta_inhibition=inhibition, wta_node=wta_node)
        ]
    if "onnx" in targets:
        written["onnx"] = [write_onnx(model, out / ONNX_NAME)]
    if "loihi" in targets:
        written["loihi"] = list(write_loihi(model, out / LOIHI_DIR, source_sha256=digest).values())
    return written


def check_spikes(args: argparse.Namespace, source) -> tuple[torch.Tensor, str]:
    """Query presentations of --query (real data), else synthetic Bernoulli trains of random images."""
    from ..encoding import encode, query_spikes
    from .evaluate import load_query_data

    cfg = source.config
    limit = args.check_samples
    if args.query:
        dataset = load_query_data(args, source, [args.query])
        images, ids = dataset.traversal(args.query), dataset.place_ids
        if limit > 0:
            images, ids = images[:limit], ids[:limit]
        return query_spikes(images, ids, args.query, cfg), f"{len(ids)} '{args.query}' queries from {dataset.source}"
    n = limit if limit > 0 else 16
    rng = np.random.default_rng(cfg.seed)
    spikes = encode(rng.random((n, cfg.network.n_inputs)).astype(np.float32), list(range(n)), cfg.encoder)
    return spikes, f"{n} synthetic presentations (uniform random pixels)"


def reference_run(source, spikes: torch.Tensor, wta: bool):
    """The project's own raster for the source (float network or integer simulator)."""
    from ..dynamics import FloatNetwork
    from ..targets.intsim import simulate

    cfg = source.config.replace(**{"network.wta": wta})
    if isinstance(source, Checkpoint):
        return FloatNetwork.from_arrays(source.weights, source.thresholds, cfg, torch.device("cpu")).run(
            spikes, record=True
        )
    return simulate(dataclasses.replace(source, config=cfg), spikes, record=True)


def row(target: str, check: str, ok: bool | None, detail: str) -> dict[str, Any]:
    return {
        "target": target,
        "check": check,
        "result": "-" if ok is None else ("ok" if ok else "FAILED"),
        "detail": detail,
    }


def decided_places(source, counts: np.ndarray) -> np.ndarray:
    """W+Prob decision (k = 1) of each presentation with the source's own calibration."""
    from ..readout.assignment import decide, strategy_scores

    return decide(strategy_scores(source.calibration, counts, "wprob", source.config.assignment.gamma), "wprob")[0]


def check_nir(path: Path, source, spikes: torch.Tensor, consumer_name: str = "nirtorch") -> list[dict]:
    from ..targets.nir_target import CONSUMERS, load_graph, read_nir, spike_agreement

    network = reference_run(source, spikes, source.config.network.wta).raster
    rebuilt = read_nir(path)
    same = torch.equal(network, reference_run(rebuilt, spikes, rebuilt.config.network.wta).raster)
    try:
        consumer = CONSUMERS[consumer_name](load_graph(path), spikes)
    except AssertionError as exc:  # snnTorch's importer asserts on what it cannot express
        return [
            row("nir", "read_nir rebuild: identical raster", same, "project importer + simulator"),
            row("nir", f"{consumer_name} loads the file", None, f"refused: {exc}"),
        ]
    agreement = spike_agreement(network, consumer)
    places = decided_places(source, network.sum(dim=1).numpy())
    consumer_places = decided_places(source, consumer.sum(dim=1).numpy())
    return [
        row("nir", "read_nir rebuild: identical raster", same, "project importer + simulator"),
        row(
            "nir",
            f"{consumer_name} (no metadata) vs network",
            None,
            f"recall {agreement['recall']:.4f}, precision {agreement['precision']:.4f}, "
            f"{consumer.sum().item() / max(1, consumer.shape[0] * consumer.shape[1]):.1f} spikes/step",
        ),
        row(
            "nir",
            f"{consumer_name} top-1 place (W+Prob) == network's",
            None,
            f"{float(np.mean(places == consumer_places)):.3f}",
        ),
    ]


def check_onnx(path: Path, model, spikes: torch.Tensor) -> list[dict]:
    from ..readout.assignment import strategy_scores
    from ..targets.intsim import simulate
    from ..targets.onnx_target import run_onnx_outputs

    run = simulate(model, spikes)
    out = run_onnx_outputs(path, spikes)
    expected = strategy_scores(model.calibration, run.counts.numpy(), "wprob", model.config.assignment.gamma)
    same_counts = np.array_equal(out.counts, run.counts.numpy())
    same_sat = int(out.saturations.sum()) == run.saturations
    close = bool(np.allclose(out.wprob, expected, rtol=1e-12, atol=1e-15))
    return [
        row("onnx", "onnxruntime counts == integer simulator", same_counts, f"{int(run.counts.sum())} spikes"),
        row("onnx", "saturations equal", same_sat, f"{int(out.saturations.sum())} clips"),
        row("onnx", "W+Prob head == readout", close, f"max |diff| {float(np.abs(out.wprob - expected).max()):.2e}"),
    ]


def check_loihi(folder: Path, model, spikes: torch.Tensor) -> list[dict]:
    from ..targets.intsim import simulate
    from ..targets.loihi_target import read_loihi_model

    rebuilt = read_loihi_model(folder)
    same = torch.equal(simulate(model, spikes, record=True).raster, simulate(rebuilt, spikes, record=True).raster)
    return [
        row(
            "loihi",
            "description rebuilds the model: identical raster",
            same,
            "the Lava run itself: tests/targets/lava_conformance (Python 3.10)",
        )
    ]


def export_and_check(
    source,
    model,
    targets: tuple[str, ...],
    out: Path,
    *,
    digest: str,
    model_path: str = "",
    inhibition: float = WTA_INHIBITION,
    wta_node: bool = True,
    spikes: torch.Tensor | None = None,
    spikes_label: str = "",
    nir_consumer: str = "nirtorch",
) -> dict[str, Any]:
    """Write the targets into ``out``, check them on ``spikes`` when given, write export.json; return its content.

    ``source`` is the Checkpoint or FixedPointModel for NIR, ``model`` the fixed-point model for
    the integer targets (``integer_model``). This is the whole command without argument parsing,
    for callers such as ``demo``.
    """
    written = export_all(source, model, targets, out, digest, inhibition, wta_node)
    manifest: dict[str, Any] = {
        "model": model_path,
        "model_sha256": digest,
        "kind": "float checkpoint" if isinstance(source, Checkpoint) else "fixed-point model",
        "files": {t: [{"path": str(p), "sha256": sha256_file(p)} for p in paths] for t, paths in written.items()},
        "consumers": consumer_statements(source, model, targets, wta_node, inhibition),
    }
    if spikes is not None:
        rows = []
        if "nir" in written:
            rows += check_nir(written["nir"][0], source, spikes, nir_consumer)
        if "onnx" in written:
            rows += check_onnx(written["onnx"][0], model, spikes)
        if "loihi" in written:
            rows += check_loihi(out / LOIHI_DIR, model, spikes)
        manifest["checks"] = {
            "spikes": spikes_label,
            "rows": rows,
            "passed": all(r["result"] != "FAILED" for r in rows),
        }
    atomic_write_text(out / MANIFEST_NAME, json.dumps(manifest, indent=2))
    return manifest


def run(args: argparse.Namespace) -> int:
    targets = parse_targets(args.to)
    source = load_model(args.model)
    digest = sha256_file(args.model)
    model = integer_model(source, args.quantize, digest, targets)
    out = Path(args.out)
    spikes, label = check_spikes(args, source) if args.check else (None, "")
    manifest = export_and_check(
        source,
        model,
        targets,
        out,
        digest=digest,
        model_path=str(args.model),
        inhibition=args.nir_inhibition,
        wta_node=not args.nir_no_wta_node,
        spikes=spikes,
        spikes_label=label,
        nir_consumer=args.nir_consumer,
    )
    if args.json:
        print_json(manifest)
    else:
        for target, files in manifest["files"].items():
            print(f"{target}: {', '.join(f['path'] for f in files)}")
            if target in manifest["consumers"]:
                print(f"  {manifest['consumers'][target]}")
        if args.check:
            print(f"\nchecks on {label}:")
            print(format_table(manifest["checks"]["rows"], CHECK_COLUMNS))
        if not args.quiet:
            print(f"\nwrote {out / MANIFEST_NAME}", file=sys.stderr)
    return 0 if not args.check or manifest["checks"]["passed"] else 1
