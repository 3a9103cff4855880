"""What every experiment shares: its data, its size (quick or full), seeds and summaries."""

from __future__ import annotations

import hashlib
import io
import json
import os
import platform
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from experiments.settings import Settings as Settings  # the experiments import it from here
from experiments.settings import Variant as Variant
from experiments.sourcehash import source_fingerprint
from vprsnn_export.config import Config
from vprsnn_export.data.dataset import Dataset, load_dataset, scoring_truth
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.device import resolve_device
from vprsnn_export.errors import DataError
from vprsnn_export.io.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from vprsnn_export.io.fileio import atomic_write_bytes, atomic_write_text
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.stats import mean_std
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.pipeline import train_and_calibrate
from vprsnn_export.version import __version__

#: The module whose functions compute what is cached (training, calibration, query spike counts): the
#: source it imports, transitively, is hashed into every cache key (:func:`code_version`).
CACHED_BY = ("experiments.common",)


def load(settings: Settings, selection: str, cfg: Config, places: str | None = None) -> Dataset:
    """``selection`` is "subset" (the 100-place subset) or "consecutive" (a run of places: ``places``, by default
    the settings'); the data set is checked to be scored by index (:func:`check_index_scored`), as every
    experiment scores it."""
    traversals = [settings.reference, settings.query]
    if selection == "subset" and settings.subset:
        data = load_dataset(settings.data, traversals, cfg.preprocess, subset=settings.subset)
    else:
        data = load_dataset(settings.data, traversals, cfg.preprocess, places=places or settings.consecutive)
    check_index_scored(data, settings.reference, settings.query)
    return data


def check_index_scored(data: Dataset, reference: str, query: str) -> None:
    """The experiments score query frame ``j`` as reference place ``j`` (``data.place_ids`` shared by both
    traversals). That is the data set's own scoring when it has no ground-truth file (a manifest, the
    synthetic route, index-aligned folders) or when its file matches each selected query to exactly its
    own index:

    .. math:: \\mathrm{GT}[r, q] = [r = q] \\quad \\forall q \\in \\text{place ids}, \\forall r

    Otherwise DataError naming the file (evaluate, simulate and verify score against it), and naming the
    folder when the traversals are not index-aligned and no file says how they match
    (:func:`vprsnn_export.data.dataset.scoring_truth`): never an index score on data that is not index-aligned."""
    truth = scoring_truth(data, [reference], query)
    if truth is None:
        return
    ids = data.place_ids
    expected = np.zeros((truth.matrix.shape[0], len(ids)), dtype=bool)
    expected[ids, np.arange(len(ids))] = True
    found = truth.matrix[:, ids]
    if not np.array_equal(found, expected):
        first = int(np.flatnonzero((found != expected).any(axis=0))[0])
        matches = np.flatnonzero(found[:, first]).tolist()
        raise DataError(
            f"its query frame {int(ids[first])} matches reference frame(s) {matches}, but experiments score query "
            f"frame j as reference place j: evaluate, simulate and verify score against this file (or give a place "
            "manifest that puts each query under its reference's place id)",
            truth.source,
        )


def provenance(settings: Settings, started: float) -> dict:
    return {
        "package_version": __version__,
        "settings": asdict(settings),
        "config_defaults": Config().to_dict(),
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, {platform.processor() or 'cpu'}",
        "python": platform.python_version(),
        "torch": torch.__version__,
        "seconds": round(time.perf_counter() - started, 1),
    }


def regenerating_command(results: dict) -> str:
    """The command that regenerates a page: the one its run recorded. Runs from before ``--out`` and
    ``--update-docs`` were recorded (no "output" key) wrote docs/results by default, which is
    ``--update-docs`` now."""
    command = str(results["command"])
    words = command.split()
    if "output" in results or "--update-docs" in words or any(w.split("=")[0] == "--out" for w in words):
        return command
    return f"{command} --update-docs"


def document(name: str, description: str, stem: str, results: dict, body: str) -> str:
    """The Markdown page of an experiment: title, description, the command that regenerates it
    (:func:`regenerating_command`) and provenance, then ``body``."""
    prov = results["provenance"]
    return (
        f"# Experiment: {name}\n\n{description}.\n\n"
        f"Generated from `{stem}.json` by `{regenerating_command(results)}` "
        f"({prov['seconds']} s on {prov['machine']}, torch {prov['torch']}, vprsnn-export {prov['package_version']}).\n\n"
        + body
    )


def pct(summary: dict) -> str:
    return f"{100 * summary['mean']:.1f} ± {100 * summary['std']:.1f}"


def cache_dir() -> Path:
    """Where experiments cache trained checkpoints: $VPRSNN_CACHE, else ~/.cache/vprsnn-export/checkpoints."""

    return Path(os.environ.get("VPRSNN_CACHE", Path.home() / ".cache" / "vprsnn-export" / "checkpoints"))


def code_version() -> str:
    """The package version and a sha256 of the source that computes cached results
    (:func:`experiments.sourcehash.source_fingerprint` of :data:`CACHED_BY`): any edit to training,
    calibration, the network or the data loading gives new cache keys, so a stale cache is never reused."""
    return f"{__version__}+{source_fingerprint(CACHED_BY)}"


def checkpoint_path(settings: Settings, data: Dataset, cfg: Config, selection_key: str) -> Path:
    """Where the checkpoint of ``cfg`` trained on ``data`` is cached: a hash of everything that determines it
    (config, data manifest hash, selected places, reference, package version and source: :func:`code_version`)."""
    config = cfg.to_dict()
    # readout-only keys added after networks were cached: left out, so those networks keep their keys
    for key in ("hyperactive_share", "outside_weight"):
        config["assignment"].pop(key)
    key = json.dumps(
        {
            "config": config,
            "manifest": data.manifest_sha256,
            "places": data.place_ids.tolist(),
            "reference": settings.reference,
            "version": code_version(),
        },
        sort_keys=True,
    )
    return cache_dir() / f"{selection_key}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.npz"


def _train(settings: Settings, data: Dataset, cfg: Config):
    return train_and_calibrate(
        data,
        [settings.reference],
        cfg,
        device=resolve_device(settings.device),
        progress=settings.progress,
        selection={"subset": None, "places": None},
        cluster=settings.cluster,
    )


def trained_checkpoint(settings: Settings, data: Dataset, cfg: Config, selection_key: str):
    """Train (or reuse) the float checkpoint of ``cfg`` on ``data``'s reference traversal.

    Training is deterministic, so a checkpoint is cached under :func:`checkpoint_path`.
    """

    path = checkpoint_path(settings, data, cfg, selection_key)
    if path.exists():
        return load_checkpoint(path)
    ckpt = _train(settings, data, cfg)
    save_checkpoint(path, ckpt)
    return ckpt


@dataclass(frozen=True)
class TimedCheckpoint:
    """A cached checkpoint and the wall-clock seconds its training and calibration took when it was trained."""

    checkpoint: Checkpoint
    train_seconds: float
    trained_on: str  # the machine and thread count of that run
    cached: bool  # True: read from the cache by this run


def timed_checkpoint(settings: Settings, data: Dataset, cfg: Config, selection_key: str) -> TimedCheckpoint:
    """:func:`trained_checkpoint` that also keeps the training time beside the cached file (``<file>.time.json``),
    so that a rerun that trains nothing still reports how long training took."""
    path = checkpoint_path(settings, data, cfg, selection_key)
    timing = path.with_name(path.name + ".time.json")
    if path.exists() and timing.exists():
        saved = json.loads(timing.read_text())
        return TimedCheckpoint(load_checkpoint(path), float(saved["train_seconds"]), str(saved["trained_on"]), True)
    started = time.perf_counter()
    ckpt = _train(settings, data, cfg)
    seconds = time.perf_counter() - started
    machine = f"{platform.machine()}, {torch.get_num_threads()} torch threads"
    save_checkpoint(path, ckpt)
    atomic_write_text(timing, json.dumps({"train_seconds": seconds, "trained_on": machine}))
    return TimedCheckpoint(ckpt, seconds, machine, False)


def rescoped_checkpoint(
    settings: Settings, data: Dataset, ckpt: Checkpoint, scope: str, selection_key: str
) -> tuple[Config, Checkpoint]:
    """The same trained network read with another ``network.wta_scope``: training never depends on the
    scope (each module is trained with its own WTA), so only the calibration S^R is recounted with the
    new WTA group; cached like a trained checkpoint under the config with that scope."""
    cfg = ckpt.config.replace(**{"network.wta_scope": scope})
    if cfg == ckpt.config:
        return cfg, ckpt
    path = checkpoint_path(settings, data, cfg, selection_key)
    if path.exists():
        return cfg, load_checkpoint(path)
    network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, cfg, resolve_device(settings.device))
    network.progress = settings.progress
    references = {name: data.traversal(name) for name in ckpt.reference_traversals}
    rescoped = replace(ckpt, config=cfg, calibration=calibrate(network.counts, references, data.place_ids, cfg))
    save_checkpoint(path, rescoped)
    return cfg, rescoped


@dataclass(frozen=True)
class TimedCounts:
    """Spike counts of a cached network on a query traversal and the seconds that run took."""

    counts: np.ndarray  # (queries, neurons) int64
    seconds: float
    cached: bool


def timed_query_counts(
    settings: Settings, data: Dataset, cfg: Config, selection_key: str, ckpt: Checkpoint
) -> TimedCounts:
    """The float network's spike counts on ``settings.query`` (state isolation on), cached beside the
    checkpoint of :func:`checkpoint_path` with the seconds the run took when it ran (a network run on
    thousands of images at thousands of neurons takes minutes; the readouts that follow take seconds)."""
    path = checkpoint_path(settings, data, cfg, selection_key)
    stem = path.name.removesuffix(".npz")
    counts_path = path.with_name(f"{stem}.{settings.query}.counts.npy")
    timing = path.with_name(f"{stem}.{settings.query}.counts.json")
    if counts_path.exists() and timing.exists():
        return TimedCounts(
            np.load(counts_path, allow_pickle=False), float(json.loads(timing.read_text())["seconds"]), True
        )
    network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, ckpt.config, resolve_device(settings.device))
    network.progress = settings.progress
    started = time.perf_counter()
    run = network.run(query_spikes(data.traversal(settings.query), data.place_ids, settings.query, ckpt.config))
    seconds = time.perf_counter() - started
    counts = run.counts.numpy().astype(np.int64)
    buffer = io.BytesIO()
    np.save(buffer, counts)
    atomic_write_bytes(counts_path, buffer.getvalue())
    atomic_write_text(timing, json.dumps({"seconds": seconds}))
    return TimedCounts(counts, seconds, False)


METRICS = ("accuracy", "p_at_100r", "r_at_100p", "auc_pr")


def summarise_rows(per_seed_rows: list[list[dict]], keys: tuple[str, ...] = ("strategy", "k")) -> list[dict]:
    """Group rows of several seeds by ``keys`` and give mean ± std of every metric."""
    groups: dict[tuple, list[dict]] = {}
    for rows in per_seed_rows:
        for row in rows:
            groups.setdefault(tuple(row[k] for k in keys), []).append(row)
    return [
        {
            **dict(zip(keys, group, strict=True)),
            **{m: mean_std(r[m] for r in rows).to_dict() for m in METRICS},
            "n_queries": rows[0]["n_queries"],
        }
        for group, rows in groups.items()
    ]


def rows_table(summary: list[dict], keys: tuple[str, ...] = ("strategy", "k")) -> str:
    """A Markdown table of summarised rows (percent, mean ± std over seeds)."""
    head = "| " + " | ".join(keys) + " | accuracy % | P@100R % | R@100P % | AUC-PR % | seeds |"
    lines = [head, "|" + "---|" * (len(keys) + 5)]
    for row in summary:
        cells = [str(row[k]) for k in keys] + [pct(row[m]) for m in METRICS] + [str(row["accuracy"]["n"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def consecutive_networks(settings: Settings):
    """For each seed: (seed, config, the consecutive-places data, its trained checkpoint)."""
    for seed in settings.seeds:
        cfg = settings.config(seed)
        data = load(settings, "consecutive", cfg)
        yield seed, cfg, data, trained_checkpoint(settings, data, cfg, "consecutive")
