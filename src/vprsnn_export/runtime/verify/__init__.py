"""Does the deployed network still recognise places like the float one? The checks of `vprsnn-export verify`.

For one float checkpoint and each weight bit width the network is deployed (:func:`runtime.deployment.deploy`),
every integer implementation runs on the very spike tensor the float network sees, and four families of checks
compare them: **cross-implementation** (exact, :mod:`runtime.conformance`), **spike level** (per-step winner
agreement, per-query count correlation, spikes, saturations), **decision level** (top-1 agreement per strategy,
W+Prob total variation, k-frame agreement) and **metric level** (every readout's metrics and their differences
from float). Tolerances (docs/verify.md) turn the differences into a verdict per width.

The checks are :mod:`.checks` and :mod:`.paired`, the run over every width :mod:`.run` (:func:`verify_checkpoint`),
a command's networks and data :mod:`.networks`, the mean ± std over runs and the report :mod:`.summary`.
"""

from .run import Runtime, VerifiedNetwork, VerifyOptions, verify_checkpoint
from .summary import build_report, summarise_runs

__all__ = ["Runtime", "VerifiedNetwork", "VerifyOptions", "build_report", "summarise_runs", "verify_checkpoint"]
