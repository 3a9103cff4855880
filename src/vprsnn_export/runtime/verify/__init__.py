"""Does the deployed network still recognise places like the float one? The checks of `vprsnn-export verify`.

For one float checkpoint and each weight bit width, the network is deployed
(:func:`runtime.deployment.deploy`: quantised and calibrated), every
integer implementation runs on the very spike tensor the float network sees
(:func:`vprsnn_export.data.encoding.query_spikes`), and four families of checks compare them:

* **cross-implementation** (exact; :mod:`runtime.conformance`): the integer simulator, the ONNX graph, the
  NIR and Loihi-style files read back and the reference stepper must give identical outputs.
* **spike level**: per-step agreement of the float and integer rasters (the WTA winner),
  the per-query Pearson correlation of the two spike-count vectors, total spikes,
  saturation events.
* **decision level**: top-1 agreement with the float decisions for every strategy, the
  total-variation distance between the two W+Prob distributions, and the agreement of
  the k-frame aggregated decisions.
* **metric level**: accuracy, P@100R, R@100P and AUC-PR of Standard, Weighted and W+Prob
  at k=1 and W+Prob aggregated at each k, and their differences from float.

Tolerances (docs/verify.md) turn the metric, spike and decision differences into
pass/fail per bit width. Every function below is pure apart from :func:`verify_checkpoint`
(which writes the exported files); results are the typed objects of :mod:`runtime.results`.

The checks are :mod:`.checks`, the run over every bit width :mod:`.run`
(:func:`verify_checkpoint` of a :class:`VerifiedNetwork` on a :class:`~vprsnn_export.data.truth.Query`,
:class:`VerifyOptions`, :class:`Runtime`), the networks and data of a command's run :mod:`.networks`, the mean ± std over runs and the
report :mod:`.summary` (:func:`build_report`).
"""

from .checks import DEFAULT_TOLERANCES, parse_tolerances
from .run import Runtime, VerifiedNetwork, VerifyOptions, verify_checkpoint
from .summary import build_report, summarise_runs

__all__ = [
    "DEFAULT_TOLERANCES",
    "Runtime",
    "VerifiedNetwork",
    "VerifyOptions",
    "build_report",
    "parse_tolerances",
    "summarise_runs",
    "verify_checkpoint",
]
