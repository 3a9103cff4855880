"""Bad arguments to the public API (issue 24), reproducible: each call either works or raises the project's error.

Builds a tiny network (synthetic:6, T = 8, 8 neurons, one epoch) and its 4-bit model, then calls
each public function with one argument replaced by each of 14 bad values (None, a string, NaN,
inf, -1, 10**30, empty arrays, an all-NaN array, a 3-D array, an object, a list, True, 1.5).
Classes: ``project`` (a VprError), ``foreign`` (any other exception: numpy, torch, AttributeError,
a bare ValueError), ``accepted`` (returned; legitimate for the values :data:`LEGAL` lists with the
reason, e.g. the string as a label), ``write-then-refuse`` (a save_* call that returned, but its
file does not load back). Run from the repository root with the project's environment active
(writes into a temp folder):

    OMP_NUM_THREADS=1 nice -n 15 python tools/bad_input_api.py [--json cases.json]

Prints one line per foreign or accepted case and the counts; ``--json``: every case with its class
and whether its acceptance is legal (tools/bad_input_campaign.py's API section reads it). Exit
status 1 when any case is foreign, write-then-refuse, or accepted without being legal.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import traceback
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import torch

import vprsnn_export as vx
from vprsnn_export.errors import VprError

BAD = {
    "none": None,
    "str": "x",
    "nan": float("nan"),
    "inf": float("inf"),
    "neg": -1,
    "huge": 10**30,
    "emptyarr": np.zeros((0,)),
    "empty2": np.zeros((0, 0)),
    "nanarr": np.full((3, 6), np.nan),
    "wrongshape": np.zeros((2, 3, 4)),
    "obj": object(),
    "list": [1, 2],
    "bool": True,
    "float": 1.5,
}


def calls(folder: Path) -> dict:
    cfg = vx.Config().replace(**{"encoder.timesteps": 8, "train.epochs": 1, "network.n_neurons": 8})
    data = vx.load_dataset("synthetic:6", ["summer", "winter"], cfg.preprocess)
    ckpt = vx.train_and_calibrate(data, ["summer"], cfg, progress=False)
    winter, places = data.traversal("winter"), data.place_ids
    ref = {"summer": data.traversal("summer")}
    readout = vx.SequenceOptions(ks=(1,))
    model = vx.deploy(ckpt, "probe", 4, reference_images=ref)
    vx.save_checkpoint(folder / "ckpt.npz", ckpt)
    vx.save_fixed_point(folder / "model.npz", model)
    sr = ckpt.calibration
    scores = np.random.default_rng(0).random((3, 6))
    frames = folder / "frames"
    frames.mkdir(exist_ok=True)
    import cv2

    for index in range(2):
        cv2.imwrite(
            str(frames / f"{index}.png"), (winter[index].reshape(-1)[: 28 * 28].reshape(28, 28) * 255).astype(np.uint8)
        )
    return {
        "Localizer": (vx.Localizer, dict(network=ckpt, threshold=0.5, options=readout)),
        "Localizer.push": (vx.Localizer(ckpt, threshold=0.5).push, dict(grey=np.zeros((32, 64), np.uint8))),
        "iter_frames": (lambda source: list(vx.iter_frames(source)), dict(source=frames)),
        "write_nir": (vx.write_nir, dict(source=model, path=folder / "m.nir", dt=1e-4)),
        "evaluate_float": (vx.evaluate_float, dict(ckpt=ckpt, query_images=winter, query_place_ids=places,
                                                   traversal="winter", options=readout)),
        "evaluate_fixed_point": (vx.evaluate_fixed_point, dict(model=model, query_images=winter,
                                                               query_place_ids=places, traversal="winter",
                                                               options=readout)),
        "query_spikes": (vx.query_spikes, dict(images=winter, place_ids=places, traversal="winter", cfg=cfg)),
        "calibration_spikes": (vx.calibration_spikes, dict(images=winter, place_ids=places, traversal="winter",
                                                           cfg=cfg)),
        "readout_rows": (vx.readout_rows, dict(calibration=sr, query_counts=np.ones((6, sr.shape[0])),
                                               reference_place_ids=places, query_place_ids=places, options=readout,
                                               config=cfg)),
        "decide": (vx.decide, dict(scores=scores, strategy="wprob")),
        "strategy_scores": (vx.strategy_scores, dict(sr=sr, sq=np.ones((3, sr.shape[0])), strategy="weighted",
                                                     gamma=0.5)),
        "pr_metrics": (vx.pr_metrics, dict(correct=np.array([True, False]), confidence=np.array([0.5, 0.2]))),
        "aggregate": (vx.aggregate, dict(prob=scores / scores.sum(1, keepdims=True), k=2, velocity=1.0)),
        "sad_distances": (vx.sad_distances, dict(reference=scores, queries=scores)),
        "sad_distribution": (vx.sad_distribution, dict(distances=scores)),
        "module_count": (vx.module_count, dict(n_places=10, module_size=3)),
        "module_regions": (vx.module_regions, dict(n_places=10, module_size=3)),
        "module_layout": (vx.module_layout, dict(cfg=cfg, n_places=6)),
        "regularise": (vx.regularise, dict(sr=sr, sq=np.ones((3, sr.shape[0])), layout=None)),
        "select_places": (vx.select_places, dict(dataset=data, place_ids=places[:2])),
        "set_threads": (vx.set_threads, dict(threads=1)),
        "quantize_checkpoint": (vx.quantize_checkpoint, dict(ckpt=ckpt, ckpt_sha256="probe", bits=4,
                                                             options=vx.QuantiseOptions())),
        "deploy": (vx.deploy, dict(ckpt=ckpt, ckpt_sha256="probe", bits=4, options=vx.QuantiseOptions(),
                                   reference_images=ref)),
        "QuantiseOptions": (vx.QuantiseOptions, dict(per_neuron=True, scale_method="max", fold_thresholds=False,
                                                     calibration="deployed", non_leaky=False)),
        "train_and_calibrate": (vx.train_and_calibrate, dict(dataset=data, references=["summer"], cfg=cfg,
                                                             progress=False)),
        "IntegerNetwork": (vx.IntegerNetwork, dict(model=model)),
        "FloatNetwork.from_arrays": (vx.FloatNetwork.from_arrays, dict(weights=ckpt.weights,
                                                                       thresholds=ckpt.thresholds, cfg=cfg,
                                                                       device=torch.device("cpu"))),
        "save_fixed_point": (vx.save_fixed_point, dict(path=folder / "out_model.npz", model=model)),
        "save_checkpoint": (vx.save_checkpoint, dict(path=folder / "out_ckpt.npz", ckpt=ckpt)),
        "load_checkpoint": (vx.load_checkpoint, dict(path=folder / "ckpt.npz")),
        "load_fixed_point": (vx.load_fixed_point, dict(path=folder / "model.npz")),
    }  # fmt: skip


#: Bad values a function may accept, with the reason: (function, argument, value label) -> why it is right.
LEGAL = {
    **{(name, "traversal", "str"): "any text names a traversal" for name in
       ("evaluate_float", "evaluate_fixed_point", "query_spikes", "calibration_spikes")},
    ("pr_metrics", "confidence", "list"): "[1, 2] are two confidences for the two decisions",
    ("aggregate", "k", "huge"): "a window longer than the stream is the whole stream (equal to k = N)",
    ("aggregate", "velocity", "neg"): "a negative velocity is a route run backwards",
    ("aggregate", "velocity", "float"): "1.5 places per frame",
    ("regularise", "layout", "none"): "None: a single network, nothing to regularise",
    ("select_places", "place_ids", "list"): "places 1 and 2 are in the data set",
    ("set_threads", "threads", "none"): "None: the default thread count",
    ("quantize_checkpoint", "ckpt_sha256", "str"): "any text labels the source",
    ("deploy", "ckpt_sha256", "str"): "any text labels the source",
    **{("QuantiseOptions", name, "bool"): "True is a valid choice" for name in
       ("per_neuron", "fold_thresholds", "non_leaky")},
    ("train_and_calibrate", "progress", "bool"): "True is a valid choice",
    ("FloatNetwork.from_arrays", "device", "none"): "None: the tensors stay where they are",
    ("save_fixed_point", "path", "str"): "'x' is a file name (written and read back)",
    ("save_checkpoint", "path", "str"): "'x' is a file name (written and read back)",
    ("load_checkpoint", "path", "str"): "reads the 'x' that save_checkpoint wrote",
    ("Localizer", "threshold", "none"): "None: accept no decision",
    ("Localizer", "options", "none"): "None: the config's readout options",
    ("write_nir", "path", "str"): "'x' is a file name",
    ("write_nir", "dt", "float"): "a 1.5 s time step",
}  # fmt: skip
READERS = {"save_fixed_point": vx.load_fixed_point, "save_checkpoint": vx.load_checkpoint}


def call_case(name: str, function, kwargs: dict, arg: str, label: str, value: object) -> dict:
    """One call with ``arg`` replaced by ``value``: its class, and the exception or the legal reason."""
    record = {"case": f"{name}({arg}={label})", "function": name, "argument": arg, "value": label}
    try:
        function(**{**kwargs, arg: value})
    except VprError as exc:
        return {**record, "class": "project", "detail": str(exc).splitlines()[0][:200] if str(exc) else ""}
    except Exception as exc:  # noqa: BLE001  (the point: any other exception is a defect)
        where = traceback.extract_tb(exc.__traceback__)[-1]
        detail = f"{type(exc).__name__}: {str(exc)[:90]} @ {Path(where.filename).name}:{where.lineno}"
        return {**record, "class": "foreign", "detail": detail}
    if name in READERS:
        path = kwargs["path"] if arg != "path" else value
        try:
            READERS[name](path)
        except Exception as exc:  # noqa: BLE001
            return {**record, "class": "write-then-refuse", "detail": f"{type(exc).__name__}: {str(exc)[:120]}"}
    reason = LEGAL.get((name, arg, label))
    return {**record, "class": "accepted", "legal": reason is not None, "detail": reason or ""}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", type=Path, help="write every case here")
    args = parser.parse_args(argv)
    out = None if args.json is None else args.json.resolve()
    warnings.simplefilter("ignore")
    vx.set_threads(1)
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)  # a drawn string is a path for save_* and load_*: written here
        for name, (function, kwargs) in calls(Path(tmp)).items():
            for arg in kwargs:
                for label, value in BAD.items():
                    record = call_case(name, function, kwargs, arg, label, value)
                    records.append(record)
                    if record["class"] != "project":
                        legal = " (legal)" if record.get("legal") else ""
                        print(f"{record['class']}{legal} {record['case']}: {record['detail']}")
    tally = Counter(r["class"] for r in records)
    illegal = sum(1 for r in records if r["class"] == "accepted" and not r["legal"])
    print(f"{len(records)} calls: {tally['project']} project error, {tally['foreign']} foreign, "
          f"{tally['accepted']} accepted ({illegal} not legal), {tally['write-then-refuse']} write-then-refuse")  # fmt: skip
    if out is not None:
        out.write_text(json.dumps({"cases": records}, indent=1) + "\n", encoding="utf-8")
    return 1 if tally["foreign"] or tally["write-then-refuse"] or illegal else 0


if __name__ == "__main__":
    sys.exit(main())
