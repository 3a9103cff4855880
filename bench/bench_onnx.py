"""Throughput of the ONNX graph on onnxruntime (CPU) beside the integer simulator, on the same spike trains.

    python bench/bench_onnx.py MODEL [--bits 8,4,2] [--data DIR --query winter] [--queries 100] [--repeat 3]

MODEL is a float checkpoint (quantised here per neuron, max-abs scales, at each --bits)
or a fixed-point model (used as is). Spike trains: the query presentations of --query
from the model's own data source (or --data), else synthetic ones. Each backend runs
--repeat times; the best wall time is reported, and the counts of both are compared.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from vprsnn_export.commands._common import format_table
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import encode, query_spikes
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.runtime.exporting import load_source
from vprsnn_export.targets.intsim import simulate
from vprsnn_export.targets.onnx_session import run_session, session
from vprsnn_export.targets.onnx_target import write_onnx

COLUMNS = (
    ("backend", "backend"),
    ("bits", "bits"),
    ("threads", "threads"),
    ("queries", "queries"),
    ("timesteps", "T"),
    ("seconds", "best s"),
    ("ms_per_query", "ms/query"),
    ("queries_per_s", "queries/s"),
    ("identical", "counts == intsim"),
)


def spikes_for(model, args: argparse.Namespace) -> tuple[torch.Tensor, str]:
    cfg = model.config
    if args.query:
        source = args.data or model.data["source"]
        selection = {"subset": model.data.get("subset"), "places": model.data.get("places")}
        dataset = load_dataset(source, [args.query], cfg.preprocess, **selection)
        images, ids = dataset.traversal(args.query)[: args.queries], dataset.place_ids[: args.queries]
        return query_spikes(images, ids, args.query, cfg), f"{len(ids)} '{args.query}' queries"
    rng = np.random.default_rng(cfg.seed)
    images = rng.random((args.queries, cfg.network.n_inputs)).astype(np.float32)
    return encode(images, list(range(args.queries)), cfg.encoder), f"{args.queries} synthetic presentations"


def best_time(run, repeat: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeat):
        began = time.perf_counter()
        result = run()
        best = min(best, time.perf_counter() - began)
    return best, result


def bench_model(model, spikes: torch.Tensor, threads: list[int], repeat: int, folder: Path) -> list[dict]:
    n, timesteps = spikes.shape[0], spikes.shape[1]
    rows = []

    def add(backend: str, thread_count: int | str, seconds: float, identical: str) -> None:
        rows.append(
            {
                "backend": backend,
                "bits": model.bits,
                "threads": thread_count,
                "queries": n,
                "timesteps": timesteps,
                "seconds": f"{seconds:.3g}",  # significant digits: a tiny model runs in well under a millisecond
                "ms_per_query": f"{1000 * seconds / n:.3g}",
                "queries_per_s": f"{n / seconds:.1f}",
                "identical": identical,
            }
        )

    torch_threads = torch.get_num_threads()
    seconds, reference = best_time(lambda: simulate(model, spikes), repeat)
    add("intsim (torch)", torch_threads, seconds, "-")
    path = write_onnx(model, folder / f"model_{model.bits}.onnx", with_wprob=False)
    for count in threads:
        sess = session(path, threads=count)
        seconds, out = best_time(lambda: run_session(sess, spikes), repeat)
        add("onnxruntime", count, seconds, "yes" if np.array_equal(out.counts, reference.counts.numpy()) else "NO")
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="float checkpoint or fixed-point model")
    parser.add_argument("--bits", default="8,4,2", help="bit widths for a float checkpoint")
    parser.add_argument("--data", help="place manifest (default: the model's own data source)")
    parser.add_argument("--query", help="query traversal (default: synthetic spike trains)")
    parser.add_argument("--queries", type=int, default=100)
    parser.add_argument("--threads", default="1,2", help="onnxruntime intra-op thread counts")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--torch-threads", type=int, help="torch intra-op threads for the simulator (default: torch's)")
    args = parser.parse_args()
    if args.torch_threads:
        torch.set_num_threads(args.torch_threads)
    source = load_source(args.model)
    if source.checkpoint is not None:
        models = [
            quantize_checkpoint(source.checkpoint, source.sha256, int(b), QuantiseOptions())
            for b in args.bits.split(",")
        ]
    else:
        assert source.fixed_point is not None
        models = [source.fixed_point]
    spikes, described = spikes_for(models[0], args)
    threads = [int(t) for t in args.threads.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for model in models:
            rows += bench_model(model, spikes, threads, args.repeat, Path(folder))
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"{described}; torch threads {torch.get_num_threads()}; {os.cpu_count()} CPUs, load average {load}")
    print(format_table(rows, COLUMNS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
