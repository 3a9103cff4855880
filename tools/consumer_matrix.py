"""The NIR consumer matrix (docs/targets.md section 1.4): every file of a trained network in every consumer.

For each checkpoint given: the float file and the 8/4/2-bit models (per-neuron thresholds and
thresholds folded), exported to NIR, run in each consumer of
``vprsnn_export.targets.nir_consumers.MATRIX_CONSUMERS`` (with the file's consumer_settings
where the name says so) and in onnxruntime, on the first ``--queries`` winter queries of the
network's own places. Each cell: A / B (P): A = raster entries where the consumer's WTA-off
raster differs from the network's WTA-off raster, B = entries where the consumer's raster
after ``apply_readout_rule`` differs from the network's raster, P = share of queries whose
decided place (W+Prob, k = 1) is the network's. Prints markdown and writes JSON.

    nice -n 15 python tools/consumer_matrix.py /tmp/nets/dog_s7.npz /tmp/nets/paper_s7.npz \
        --data ../shared/data/nordland_64x32_summer_winter --out /tmp/matrix.json --threads 1
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
import time
from pathlib import Path

import nir
import numpy as np
import torch

from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import Checkpoint, load_checkpoint
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.runtime.consumer_gate import decided_places
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.nir_consumers import MATRIX_CONSUMERS, ConsumerUnavailable, run_consumer
from vprsnn_export.targets.nir_target import apply_readout_rule, write_nir
from vprsnn_export.targets.onnx_session import run_onnx_outputs
from vprsnn_export.targets.onnx_target import write_onnx
from vprsnn_export.threads import set_threads

FILES = ("float", "8bit", "4bit", "2bit", "8bit-folded", "4bit-folded", "2bit-folded")


def network_raster(source: Checkpoint | FixedPointModel, spikes: torch.Tensor, wta: bool) -> torch.Tensor:
    cfg = source.config.replace(**{"network.wta": wta})
    if isinstance(source, Checkpoint):
        run = FloatNetwork.from_arrays(source.weights, source.thresholds, cfg, torch.device("cpu")).run(
            spikes, record=True
        )
    else:
        run = simulate(dataclasses.replace(source, config=cfg), spikes, record=True)
    assert run.raster is not None
    return run.raster.to(torch.bool)


def sources_of(ckpt: Checkpoint) -> dict[str, Checkpoint | FixedPointModel]:
    sources: dict[str, Checkpoint | FixedPointModel] = {"float": ckpt}
    for fold in (False, True):
        for bits in (8, 4, 2):
            sources[f"{bits}bit" + ("-folded" if fold else "")] = quantize_checkpoint(
                ckpt, "0" * 64, bits, QuantiseOptions(fold_thresholds=fold)
            )
    return sources


def cell(graph, source, spikes, off_net, on_net, places, consumer: str) -> dict[str, object]:
    try:
        raster = run_consumer(consumer, graph, spikes)
    except (AssertionError, ValueError, ConsumerUnavailable) as exc:
        return {"refused": f"{type(exc).__name__}: {str(exc).splitlines()[0][:160]}"}
    ruled = apply_readout_rule(graph, spikes, raster)
    agree = float(np.mean(decided_places(source, ruled.sum(dim=1).numpy()) == places))
    return {"off": int((raster != off_net).sum()), "ruled": int((ruled != on_net).sum()), "agreement": agree}


def matrix_of(path: Path, data: str, queries: int, folder: Path) -> dict[str, dict[str, dict[str, object]]]:
    ckpt = load_checkpoint(path)
    cfg = ckpt.config
    dataset = load_dataset(
        data, ["winter"], cfg.preprocess, subset=ckpt.data.get("subset"), places=ckpt.data.get("places")
    )
    spikes = query_spikes(dataset.traversal("winter")[:queries], dataset.place_ids[:queries], "winter", cfg)
    rows: dict[str, dict[str, dict[str, object]]] = {}
    for name, source in sources_of(ckpt).items():
        graph = nir.read(write_nir(source, folder / f"{path.stem}-{name}.nir"))
        off_net, on_net = network_raster(source, spikes, False), network_raster(source, spikes, True)
        places = decided_places(source, on_net.sum(dim=1).numpy())
        row = {
            consumer: cell(graph, source, spikes, off_net, on_net, places, consumer) for consumer in MATRIX_CONSUMERS
        }
        row["candidates/step"] = {"value": float(off_net.sum()) / (off_net.shape[0] * off_net.shape[1])}
        if isinstance(source, FixedPointModel):
            out = run_onnx_outputs(write_onnx(source, folder / f"{path.stem}-{name}.onnx", with_raster=True), spikes)
            assert out.raster is not None
            agree = float(np.mean(decided_places(source, out.counts) == places))
            row["onnxruntime"] = {"off": None, "ruled": int((torch.from_numpy(out.raster) != on_net).sum())}
            row["onnxruntime"]["agreement"] = agree
        rows[name] = row
    return rows


def fmt(entry: dict[str, object]) -> str:
    if "refused" in entry:
        return "refuses"
    if "value" in entry:
        return f"{entry['value']:.1f}"
    off = "-" if entry["off"] is None else f"{entry['off']:,}"
    return f"{off} / {entry['ruled']:,} ({100 * float(entry['agreement']):.0f} %)"  # type: ignore[arg-type]


def markdown(name: str, rows: dict[str, dict[str, dict[str, object]]]) -> str:
    columns = list(MATRIX_CONSUMERS) + ["onnxruntime", "candidates/step"]
    lines = [f"**{name}**", "", "| file | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for file, row in rows.items():
        lines.append(f"| {file} | " + " | ".join(fmt(row[c]) if c in row else "-" for c in columns) + " |")
    refusals = {f"{c}: {row[c]['refused']}" for row in rows.values() for c in MATRIX_CONSUMERS if "refused" in row[c]}
    return "\n".join(lines + [""] + [f"* {r}" for r in sorted(refusals)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("checkpoints", nargs="+", type=Path, help="trained checkpoints (.npz)")
    parser.add_argument("--data", required=True, help="the dataset folder the checkpoints were trained on")
    parser.add_argument("--queries", type=int, default=100, help="winter queries (default 100)")
    parser.add_argument("--out", type=Path, help="write the measured cells as JSON here")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    set_threads(args.threads)
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.checkpoints:
            began = time.perf_counter()
            results[path.name] = matrix_of(path, args.data, args.queries, Path(tmp))
            print(markdown(path.name, results[path.name]))
            print(f"\n({time.perf_counter() - began:.0f} s)\n", flush=True)
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
