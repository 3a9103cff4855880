"""What every exported file states so that a user reproduces the project's decisions without the project.

The encoder contract (:func:`encoder_contract`): the query spikes of a preprocessed image x (inputs,)
of place id ``place_id`` in the traversal named ``traversal``, bit for bit
:func:`vprsnn_export.data.encoding.query_spikes`:

    p_i     = clip(rate_scale x_i, 0, 1)                                              (float32)
              (with a learnt ``input_gain`` g: x_i -> g_i x_i / max_j g_j x_j first, 0 when that max is 0)
    g       = int.from_bytes(sha256("vprsnn/v1|<seed>|query|<traversal>|<place_id>|0")[:8], "little") mod 2**63
    w_k     = the k-th 32-bit word of MT19937 after init_genrand(g mod 2**32)        (k = t inputs + i)
    s[t, i] = (w_k mod 2**24) < ceil(p_i 2**24)

The search rule (:func:`search_rule`): the modules a frame of a tracking localiser runs and how it follows.

The decision rule (:func:`decision_rule`): the W+Prob distribution P(l | Q) of one frame (the
ONNX ``wprob`` output) decides place ``reference_place_ids[argmax_l P]`` (first l on ties), none
when P is flat (max == min), with confidence max_l P (:func:`vprsnn_export.readout.strategies.decide`).
"""

from __future__ import annotations

import json
from typing import Any

from vprsnn_export.config import Config
from vprsnn_export.data.encoding import STREAM_QUERY
from vprsnn_export.data.preprocess import CHANNELS

CONTRACT_VERSION = 1


def encoder_contract(cfg: Config) -> dict[str, Any]:
    """The preprocessing and the spike generator with its seed rule (module docstring), as JSON-ready facts."""
    enc, pre = cfg.encoder, cfg.preprocess
    inputs = cfg.network.n_inputs
    return {
        "version": CONTRACT_VERSION,
        "input": f"x: one preprocessed image, {inputs} float32 values in [0, 1]",
        "preprocess": {
            **cfg.to_dict()["preprocess"],
            "inputs": inputs,
            "rule": f"greyscale, resize to {pre.image_size} x {pre.image_size} (OpenCV INTER_AREA), then the "
            f"'{pre.channels}' channels ({CHANNELS.get(pre.channels).label}; the equations: the docstring of "
            "vprsnn_export.data.preprocess), flattened row-major",
        },
        "rate_scale": enc.rate_scale,
        "timesteps": enc.timesteps,
        "seed": cfg.seed,
        "probability": "p_i = clip(rate_scale * x_i, 0, 1) in float32"
        + (
            "; first x_i -> g_i x_i / max_j g_j x_j (float32; 0 when that max is 0) with g = input_gain"
            if enc.input_gain
            else ""
        ),
        **({"input_gain": list(enc.input_gain)} if enc.input_gain else {}),
        "generator_seed": "g = int.from_bytes(hashlib.sha256(key.encode('utf-8')).digest()[:8], 'little') "
        f"& (2**63 - 1), key = 'vprsnn/v1|{cfg.seed}|{STREAM_QUERY}|<traversal>|<place_id>|0' "
        "(the query traversal's name and the query's place id, a decimal integer)",
        "generator": "MT19937 initialised by init_genrand(g mod 2**32) (torch.Generator().manual_seed(g); numpy: "
        f"numpy.random.RandomState(g % 2**32).randint(0, 2**32, size={enc.timesteps} * {inputs}, "
        "dtype=numpy.uint32)); word k = t * inputs + i",
        "spike": "s[t, i] = 1 if (word_k mod 2**24) < ceil(p_i * 2**24) else 0 (p_i as float64), i.e. "
        "torch.rand((timesteps, inputs), generator) < p",
        "project_function": "vprsnn_export.data.encoding.query_spikes(images, place_ids, traversal, config) "
        "returns these spikes (N, timesteps, inputs) uint8; numpy.save writes them beside the model",
    }


def decision_rule(output: str) -> dict[str, Any]:
    """How the W+Prob distribution named ``output`` of one frame becomes the project's decision (module docstring)."""
    return {
        "version": CONTRACT_VERSION,
        "strategy": "W+Prob, one frame (k = 1)",
        "distribution": f"P = {output}[n] (places,)",
        "place": "reference_place_ids[argmax_l P[l]], the first l on ties",
        "no_match": "no decision (place -1, confidence 0) when every P[l] is equal (max == min)",
        "confidence": "max_l P[l]",
    }


def search_rule(module_size: int, places: int) -> dict[str, Any]:
    """The tracking rule of ``localize --search-window`` (:class:`vprsnn_export.readout.search.SearchWindow`) on an
    ensemble of ``module_size``-place modules over ``places`` reference places: which modules a frame runs, how
    it is decided among their places and where the window goes next."""
    return {
        "version": CONTRACT_VERSION,
        "parameters": "w places (--search-window), p frames (--patience, default 3), d places (--follow-within, "
        "default none), a frames (--lost-after, default none); theta, the operating point's confidence threshold",
        "regions": f"module m holds places [m {module_size}, min((m + 1) {module_size}, {places}))",
        "window": "b = min(max(round(c) - floor(w / 2), 0), max(L - w, 0)) (round: half to even), L places; run the "
        "modules whose places meet [b, min(b + w, L)) "
        "(first .. last - 1), one WTA over the neurons run; the first frame and a frame with c = none run every module",
        "run": "ONNX: feed modules = [first, last); Loihi-style: power only the cores of populations exc_first .. "
        "exc_{last - 1} (network.json modules); every other core is idle for the frame",
        "decision": "the W+Prob distribution (eq. 9-13) of the run's counts, 0 for every other neuron, taken over the "
        "places of modules first .. last - 1 alone (min-max and L1 normalised there; the uniform row, no match, "
        "when flat), aggregated over the last k frames as in the batch readout: place argmax, confidence max, "
        "accepted when confidence >= theta",
        "follow": "c, misses, waited after a frame at place l (index), velocity v: a global frame sets c = l (none: "
        "global again), misses = 0 if accepted else p - 1, waited = 0; a window frame: accepted -> c = l, misses = "
        "waited = 0; else waited + 1 and |l - (c + v)| <= d -> c = l, misses unchanged; else misses + 1 and c = none "
        "(global) once misses reach p, c + v before; lost once waited reaches a: c = none, the last k frames are "
        "forgotten (the aggregate starts again), and frames stay global until one is accepted",
        "project_function": "vprsnn_export.readout.search.SearchWindow; vprsnn-export localize MODEL --search-window "
        "w [--patience p] [--follow-within d] (each decision names its modules [first, last))",
    }


def as_json(facts: Any) -> str:
    """The compact, key-sorted JSON of ``facts`` a file stores as one metadata string."""
    return json.dumps(facts, sort_keys=True, separators=(",", ":"))
