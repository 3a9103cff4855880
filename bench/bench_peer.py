"""VPRTempo beside our network and the template matcher: training time, latency per query, accuracy, events.

    OMP_NUM_THREADS=1 python bench/bench_peer.py [--data D] [--subset CSV] [--reference summer] [--query winter]
                                               [--seed 0] [--repeats 5] [--epochs N]
                                               [--peer-dims H,W] [--peer-state FILE] [--preset dog,lean]

One run, one torch thread, the same places for every method: trained on the --reference images of the --subset
places (default: the Nordland 100-place subset), queried with their --query images; a query is correct when its
best place is its own (k = 1, exact match). Rows:

* ``vprtempo``: the peer (Hines et al., VPRTempo), the ``vprtempo`` package with its published defaults (56 x 56
  input through its own ProcessImage: gamma, resize, 15-pixel patch normalisation; a feature layer of 2 x inputs
  and one output neuron per place; 4 epochs of its STDP with spike forcing), trained layer by layer with its own
  ``train_model`` and queried through its inference class ``VPRTempo`` (one pass of its two weight matrices). Its
  modules use torchvision only in their file loading; here the images reach it as tensors (torchvision's PyPI
  wheels need the CUDA build of torch: where it does not import, a stand-in that raises if called satisfies the
  imports). Missing package: the row says how to install it and the other rows still run.
* ``ours T=...``: the default network (``ours (lean) ...``: each other --preset's) trained on the subset (``train_and_calibrate``), queried at its window with
  the float kernel: encoding, the network, the W+Prob readout (``Readout.wprob`` one query at a time,
  ``Readout.scores`` batched).
* ``ours margin`` / ``ours spikes K``: the early decision (``config.early``, readout/early.py), run until the rule
  fires: the window is run on a prefix of w steps (w = 32, 64, ... up to T, each from V = 0: state isolation makes
  the prefix exact) until the rule fires within it; every rerun is timed. The counts are checked against the
  library's decision on the whole window.
* ``ours T=T' (rate x)``: a shorter window with the rate scaled by T / T' (the input spikes kept), calibrated again
  at T' (docs/results/cost.md); only for a network whose window is longer than T'.
* ``cosine``: the template matcher (cosine nearest neighbour on our preprocessed images).

Latency: "1 query" is the median over --repeats of the mean time per query when the queries come one at a time;
"batched" is the median over --repeats of the time for all queries in one call, divided by their number. Both
start from each method's preprocessed image (ours: the preprocessed row; VPRTempo: its ProcessImage output) and end
with the decided place. Events: synaptic events per query (input spikes x fan-out, network/cost.py); the template's
column is its multiply-adds. The lines after the table give ours / VPRTempo per row.
"""

from __future__ import annotations

import argparse
import logging
import re
import statistics
import sys
import time
import types
from argparse import Namespace
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from vprsnn_export.config import PRESETS, Config, EarlyConfig, preset, wta_group
from vprsnn_export.data.dataset import Dataset, load_dataset, read_manifest
from vprsnn_export.data.encoding import query_spikes
from vprsnn_export.data.truth import EXACT
from vprsnn_export.errors import VprError
from vprsnn_export.io.checkpoint import Checkpoint
from vprsnn_export.io.fileio import read_container, write_container
from vprsnn_export.network.cost import query_cost
from vprsnn_export.network.dynamics import FloatNetwork
from vprsnn_export.readout.baseline import cosine_similarities
from vprsnn_export.readout.early import early_decision, stop_steps, vote_matrix
from vprsnn_export.readout.scoring import Readout, nearest_neighbour_rows, readout_rows
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.threads import set_threads
from vprsnn_export.trainer.calibrate import calibrate
from vprsnn_export.trainer.pipeline import train_and_calibrate

NORDLAND = Path("../shared/data/nordland_64x32_summer_winter")
PEER_VERSION = "1.1.10"
INSTALL = f'pip install -c constraints.txt ".[peers]" && pip install --no-deps vprtempo=={PEER_VERSION}'
FIRST_PREFIX = 32  # steps of the first prefix an early rule is run on
EARLY_SPIKES = 25
SHORT_WINDOW = 150  # docs/results/cost.md: T=150 with the rate scaled keeps accuracy at k = 1, 5, 10


@dataclass
class Row:
    method: str
    train_s: float
    single_ms: float
    batched_ms: float
    accuracy: float
    events: float | None = None


def median_time(repeats: int, fn: Callable[[], object]) -> float:
    """Median wall time of ``fn`` over ``repeats`` calls, seconds."""
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def latencies(decide: Callable[[slice], np.ndarray], n: int, repeats: int) -> tuple[float, float, np.ndarray]:
    """(ms per query one at a time, ms per query batched, the decisions); the two must decide alike."""
    single = median_time(repeats, lambda: [decide(slice(q, q + 1)) for q in range(n)]) / n
    batched = median_time(repeats, lambda: decide(slice(0, n))) / n
    one_by_one = np.concatenate([decide(slice(q, q + 1)) for q in range(n)])
    decisions = decide(slice(0, n))  # last: a caller's record of the run is the batched one
    assert np.array_equal(decisions, one_by_one), "one query at a time and batched decide differently"
    return 1000 * single, 1000 * batched, decisions


# ------------------------------------------------------------------------------------------------ VPRTempo


def _torchvision_stand_in() -> None:
    """Satisfy VPRTempo's imports of torchvision (file reading only) with functions that raise if called."""

    def unused(*_args: object, **_kwargs: object) -> None:
        raise RuntimeError("torchvision is not used here: the images reach VPRTempo as tensors")

    package, io, transforms = (types.ModuleType(n) for n in ("torchvision", "torchvision.io", "torchvision.transforms"))
    io.read_image = unused  # type: ignore[attr-defined]
    transforms.Compose = unused  # type: ignore[attr-defined]
    package.io, package.transforms = io, transforms  # type: ignore[attr-defined]
    sys.modules.update({"torchvision": package, "torchvision.io": io, "torchvision.transforms": transforms})


def import_vprtempo() -> types.SimpleNamespace | None:
    """VPRTempo's inference class, training class and image transform, or None when the package is missing."""
    try:
        import torchvision  # noqa: F401
    except Exception:  # absent, or a CUDA wheel beside the CPU torch: its libraries do not load
        _torchvision_stand_in()
    try:
        from vprtempo.src.dataset import ProcessImage
        from vprtempo.VPRTempo import VPRTempo
        from vprtempo.VPRTempoTrain import VPRTempoTrain
    except ImportError:
        return None
    return types.SimpleNamespace(VPRTempo=VPRTempo, VPRTempoTrain=VPRTempoTrain, ProcessImage=ProcessImage)


def vprtempo_defaults(places: int, reference: str, query: str) -> Namespace:
    """VPRTempo's published command-line defaults (its main.py), with our places and traversals. ``filter`` = 1:
    its default 8 strides through the raw Nordland frames, and the subset's places are already chosen;
    ``max_module`` = the places: one module of one output neuron per place (its main.py cannot split fewer places
    than its default 500 into modules, and its learning rates anneal over max_module x epochs presentations)."""
    return Namespace(
        dataset="nordland",
        data_dir="",
        database_places=places,
        query_places=places,
        max_module=places,
        database_dirs=reference,
        query_dir=query,
        GT_tolerance=0,
        skip=0,
        filter=1,
        epoch=4,
        patches=15,
        dims="56,56",
        train_new_model=True,
        quantize=False,
        PR_curve=False,
        sim_mat=False,
        demo=False,
    )


def raw_images(data: Path, place_ids: np.ndarray, traversal: str) -> list[torch.Tensor]:
    """The places' images as torchvision's read_image gives them: (C, H, W) uint8, RGB."""
    manifest = read_manifest(data)
    out = []
    for place in place_ids.tolist():
        path = manifest.path.parent / manifest.rows[place][1][traversal]
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise SystemExit(f"bench_peer: cannot read image {path}")
        image = image[None] if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2RGB).transpose(2, 0, 1)
        out.append(torch.from_numpy(np.ascontiguousarray(image)))
    return out


def train_vprtempo(
    peer: types.SimpleNamespace, settings: Namespace, dims: list[int], reference: torch.Tensor, seed: int
) -> dict[str, torch.Tensor]:
    """VPRTempo's train_new_model for one module: its layers in order, each by its own train_model over a shuffled
    loader of the reference tensors (instead of its file loader); its trained state."""
    torch.manual_seed(seed)
    np.random.seed(seed)  # its layers draw their connections from numpy's global generator
    loader = torch.utils.data.DataLoader(
        torch.utils.data.TensorDataset(reference, torch.arange(len(reference))),
        batch_size=1,
        shuffle=True,
        generator=torch.Generator().manual_seed(seed),
    )
    trainer = peer.VPRTempoTrain(settings, dims, logging.getLogger("vprtempo"), 1, len(reference))
    trained: list[str] = []
    for name, _ in sorted(trainer.layer_dict.items(), key=lambda item: item[1]):
        trainer.train_model(loader, getattr(trainer, name), trainer, 0, prev_layers=trained)
        trained.append(name)
    return trainer.state_dict()


def load_state(path: Path, key: dict) -> tuple[dict[str, torch.Tensor] | None, float]:
    """A trained state written by an earlier run with the same ``key`` and its training seconds; (None, 0) when the
    file does not exist yet. A file trained otherwise is refused (one line)."""
    if not path.exists():
        return None, 0.0
    meta, arrays = read_container(path, "VPRTempo state")
    if {k: meta.get(k) for k in key} != key:
        raise SystemExit(
            f"bench_peer: --peer-state {path} holds VPRTempo trained with other settings (remove it to retrain)"
        )
    return {name: torch.from_numpy(value) for name, value in arrays.items()}, float(meta["train_s"])


def vprtempo_row(peer: types.SimpleNamespace, data: Path, places: np.ndarray, args: argparse.Namespace) -> Row:
    """Train VPRTempo on the reference images (its train_new_model's layer loop, tensors for its file loader) and
    query it through its inference class."""
    settings = vprtempo_defaults(len(places), args.reference, args.query)
    if args.epochs is not None:
        settings.epoch = args.epochs
    if args.peer_dims is not None:
        settings.dims = args.peer_dims
    dims = [int(x) for x in settings.dims.split(",")]
    transform = peer.ProcessImage(dims, settings.patches)
    reference = torch.stack([transform(image) for image in raw_images(data, places, args.reference)]).float()
    queries = torch.stack([transform(image) for image in raw_images(data, places, args.query)]).float()
    key = {"vprtempo": PEER_VERSION, "settings": vars(settings), "places": places.tolist(), "seed": args.seed}
    state, train_s = load_state(args.peer_state, key) if args.peer_state else (None, 0.0)
    if state is None:
        started = time.perf_counter()
        state = train_vprtempo(peer, settings, dims, reference, args.seed)
        train_s = time.perf_counter() - started
        if args.peer_state:
            arrays = {name: value.numpy() for name, value in state.items()}
            write_container(args.peer_state, {**key, "train_s": train_s}, arrays)
    model = peer.VPRTempo(settings, dims, logging.getLogger("vprtempo"), 1, None, len(places))
    model.load_state_dict(state)
    model.eval()
    model.inferences = [torch.nn.Sequential(model.feature_layer.w, model.output_layer.w)]  # as its evaluate does

    def decide(part: slice) -> np.ndarray:
        with torch.no_grad():
            return model.forward(queries[part]).argmax(dim=1).numpy()

    single, batched, decisions = latencies(decide, len(places), args.repeats)
    return Row("vprtempo", train_s, single, batched, 100 * float(np.mean(decisions == np.arange(len(places)))))


# ------------------------------------------------------------------------------------------------ ours


def prefix_decision(network: FloatNetwork, spikes: torch.Tensor, votes: np.ndarray, group: int, rule: EarlyConfig):
    """The early decision of ``rule`` run until it fires: prefixes of 32, 64, ... steps (each from V = 0), a query
    done once its stop step lies within the prefix (the rule at step t reads only steps < t and T), else T."""
    n, timesteps = spikes.shape[0], spikes.shape[1]
    steps = np.full(n, timesteps, dtype=np.int64)
    counts = np.zeros((n, votes.shape[0]), dtype=np.int64)
    pending, window = np.arange(n), min(FIRST_PREFIX, timesteps)
    while pending.size:
        raster = network.run(spikes[pending, :window], record=True).raster
        assert raster is not None  # recorded
        padded = np.zeros((pending.size, timesteps, votes.shape[0]), dtype=np.bool_)
        padded[:, :window] = raster.numpy()
        stops = stop_steps(padded, votes, group, rule)
        done = (stops <= window) | (window == timesteps)
        used = np.arange(window)[None, :] < stops[done, None]
        steps[pending[done]] = stops[done]
        counts[pending[done]] = np.einsum("ntj,nt->nj", padded[done, :window], used, dtype=np.int64)
        pending, window = pending[~done], min(2 * window, timesteps)
    return steps, counts


def our_rows(ckpt: Checkpoint, train_s: float, dataset: Dataset, args: argparse.Namespace) -> list[Row]:
    images = dataset.traversal(args.query)
    ids = dataset.place_ids
    cfg = ckpt.config
    timesteps, rate = cfg.encoder.timesteps, cfg.encoder.rate_scale
    short = cfg.replace(**{"encoder.timesteps": SHORT_WINDOW, "encoder.rate_scale": rate * timesteps / SHORT_WINDOW})
    ours = "ours" if args.preset_name == "dog" else f"ours ({args.preset_name})"
    variants: list[tuple[str, Config, EarlyConfig | None]] = [
        (f"{ours} T={timesteps}", cfg, None),
        (f"{ours} margin", cfg, EarlyConfig(margin=True)),
        (f"{ours} spikes {EARLY_SPIKES}", cfg, EarlyConfig(spikes=EARLY_SPIKES)),
    ]
    if SHORT_WINDOW < timesteps:
        variants.append((f"{ours} T={SHORT_WINDOW} (rate x{timesteps / SHORT_WINDOW:g})", short, None))
    rows = []
    neurons = int(ckpt.weights.shape[1])
    for name, run_cfg, rule in variants:
        extra_s, calibration = 0.0, ckpt.calibration
        network = FloatNetwork.from_arrays(ckpt.weights, ckpt.thresholds, run_cfg, torch.device("cpu"))
        if run_cfg is not cfg:  # another window: calibrated again there
            started = time.perf_counter()
            references = {r: dataset.traversal(r) for r in ckpt.reference_traversals}
            calibration = calibrate(network.counts, references, ids, run_cfg)
            extra_s = time.perf_counter() - started
        readout = Readout.of(calibration, run_cfg, SequenceOptions())
        votes = vote_matrix(calibration, run_cfg)
        group = wta_group(run_cfg, neurons)
        found: dict[str, np.ndarray] = {}

        def decide(part: slice) -> np.ndarray:
            spikes = query_spikes(images[part], ids[part], args.query, run_cfg)
            if rule is None:
                counts = network.run(spikes).counts.numpy()
            else:
                found["steps"], counts = prefix_decision(network, spikes, votes, group, rule)
            found["counts"] = counts
            if counts.shape[0] == 1:
                return readout.wprob(counts[0]).argmax()[None]
            return readout.scores(counts)["wprob"].argmax(axis=1)

        single, batched, _ = latencies(decide, len(ids), args.repeats)
        spikes = query_spikes(images, ids, args.query, run_cfg)
        steps = None
        if rule is not None:  # the bench's check: the prefix runs give the library's decision on the whole window
            whole = early_decision(network.run(spikes, record=True).raster.numpy(), votes, group, rule)
            assert np.array_equal(whole.steps, found["steps"]) and np.array_equal(whole.counts, found["counts"])
            steps = whole.steps
        cost = query_cost(spikes, neurons, places=len(ckpt.reference_place_ids), images=images, steps=steps)
        metric = readout_rows(calibration, found["counts"], ckpt.reference_place_ids, ids, SequenceOptions(), run_cfg)
        accuracy = 100 * next(r.accuracy for r in metric if r.strategy == "wprob" and r.k == 1)
        rows.append(Row(name, train_s + extra_s, single, batched, accuracy, cost.summary().synaptic_events))
    return rows


def cosine_row(ckpt: Checkpoint, dataset: Dataset, args: argparse.Namespace) -> Row:
    images, ids = dataset.traversal(args.query), dataset.place_ids
    reference = np.mean([dataset.traversal(r) for r in ckpt.reference_traversals], axis=0)

    def decide(part: slice) -> np.ndarray:
        return cosine_similarities(reference, images[part]).argmax(axis=1)

    single, batched, _ = latencies(decide, len(ids), args.repeats)
    rows = nearest_neighbour_rows(
        cosine_similarities(reference, images), "cosine", ckpt.reference_place_ids, ids, SequenceOptions(), EXACT
    )
    accuracy = 100 * next(r.accuracy for r in rows if r.k == 1)
    spikes = query_spikes(images, ids, args.query, ckpt.config)
    macs = query_cost(spikes, 1, places=len(ckpt.reference_place_ids), images=images).summary().template_macs
    return Row("cosine", 0.0, single, batched, accuracy, macs)


# ------------------------------------------------------------------------------------------------ table


def print_table(rows: list[Row]) -> None:
    print(
        f"{'method':<28} {'train s':>8} {'ms/query 1':>11} {'ms/query batched':>17} {'acc k=1 %':>10} "
        f"{'events/query':>14}"
    )
    for r in rows:
        events = "-" if r.events is None else f"{r.events:,.0f}"
        print(
            f"{r.method:<28} {r.train_s:>8.1f} {r.single_ms:>11.3f} {r.batched_ms:>17.3f} {r.accuracy:>10.1f} "
            f"{events:>14}"
        )
    peer = next((r for r in rows if r.method == "vprtempo"), None)
    if peer is None:
        return
    for r in rows:
        if r.method.startswith("ours"):
            print(
                f"{r.method} / vprtempo: {r.single_ms / peer.single_ms:.1f}x per query, "
                f"{r.batched_ms / peer.batched_ms:.1f}x batched, accuracy {r.accuracy - peer.accuracy:+.1f} points"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=NORDLAND, help="data set folder (a places.csv manifest)")
    parser.add_argument("--subset", type=Path, help="places to use (default: DATA/subset_100_places.csv)")
    parser.add_argument("--reference", default="summer", help="traversal trained on")
    parser.add_argument("--query", default="winter", help="traversal queried")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats (the median is printed)")
    parser.add_argument("--epochs", type=int, help="VPRTempo epochs (default: its own, 4)")
    parser.add_argument("--peer-dims", help="VPRTempo input size H,W (default: its own, 56,56)")
    parser.add_argument(
        "--peer-state",
        type=Path,
        help="VPRTempo's trained weights: read when the file exists (trained with the same settings, its training "
        "seconds printed again), else trained and written there",
    )
    parser.add_argument("--preset", default="dog", help=f"our networks, comma-separated ({', '.join(PRESETS)})")
    args = parser.parse_args()
    subset = args.subset or args.data / "subset_100_places.csv"
    for flag, path in (("--data", args.data / "places.csv"), ("--subset", subset)):
        if not path.is_file():
            parser.error(f"{flag}: no such file {path}")
    if args.repeats < 1 or (args.epochs is not None and args.epochs < 1):
        parser.error("--repeats and --epochs expect integers >= 1")
    if args.peer_dims is not None and not re.fullmatch(r"[1-9][0-9]*,[1-9][0-9]*", args.peer_dims):
        parser.error(f"--peer-dims expects H,W (two positive integers), got {args.peer_dims!r}")
    presets = args.preset.split(",")
    if not set(presets) <= set(PRESETS):
        parser.error(f"--preset: choose from {', '.join(PRESETS)}")
    set_threads(1)
    rows = []
    peer = import_vprtempo()
    for name in presets:
        cfg = preset(name).replace(seed=args.seed)
        dataset = load_dataset(args.data, [args.reference, args.query], cfg.preprocess, subset=subset)
        started = time.perf_counter()
        ckpt = train_and_calibrate(dataset, [args.reference], cfg, progress=False, threads=1)
        train_s = time.perf_counter() - started
        if not rows:
            if peer is None:
                print(f"vprtempo: not installed, its row is left out ({INSTALL})")
            else:
                rows.append(vprtempo_row(peer, args.data, dataset.place_ids, args))
        rows += our_rows(ckpt, train_s, dataset, Namespace(**vars(args), preset_name=name))
    rows.append(cosine_row(ckpt, dataset, args))
    print(
        f"data: {args.data} ({len(dataset.place_ids)} places of {subset.name}), {args.reference} -> {args.query}; "
        f"torch {torch.__version__}, {torch.get_num_threads()} thread, CPU; median of {args.repeats} repeats"
    )
    print_table(rows)


if __name__ == "__main__":
    try:
        main()
    except VprError as exc:  # a data set or state file that does not read: one line, exit 2
        print(f"bench_peer: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
