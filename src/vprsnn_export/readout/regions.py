"""Region regularisation of an ensemble: region-specific assignment and silencing of hyperactive neurons.

An ensemble of modules (``src/vprsnn_export/network/modules.py``) applies the hard WTA within each module, so every
module has a winner for every image, including the images of the other modules' regions. The calibration S^R spans every
module's neurons over every reference place, so it shows which neurons also respond outside their own module's region.
Hussaini et al. (RA-L 2022, "Ensembles of compact, region-specific & regularized SNNs") call the neurons that respond to
many places outside their region *hyperactive* and silence them at deployment, and assign each module's neurons to the
places of its own region; both use the reference (calibration) responses only. Here:

    R(i)      = the region (consecutive reference places) of neuron i's module        modules.region_mask
    S~[i, l]  = S^R[i, l] if l in R(i), else lambda S^R[i, l]                         region_weighting
    o_i       = #{ l not in R(i) : S^R[i, l] > 0 } / #{ l not in R(i) }               outside_involvement
    silent_i  = o_i > rho                                                             hyperactive_neurons
    S~[i, :] = 0 and S^Q[:, i] = 0 for every silent neuron i                          silenced_counts

and the readout (Standard, Weighted, W+Prob, aggregation) then runs on S~ in place of S^R.
lambda = ``assignment.outside_weight`` and rho = ``assignment.hyperactive_share``, both in [0, 1]; lambda = 0 is
Hussaini's region-specific assignment (a neuron votes only for places of its region), lambda = 1 the whole-route
assignment; rho = 1 silences no neuron (o_i <= 1). A single network (one module: no place lies outside its region,
o_i = 0) is never changed. A silenced neuron neither votes nor counts as active in the missing-spikes penalty (eq. 11):
it is removed from the readout as if it had not been there; its module's WTA is unchanged. Everything is computed on
the stored entries of S^R (CSR), without a loop over neurons or modules.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from vprsnn_export.arguments import require_type
from vprsnn_export.config import Config
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.serial import JsonDataclass
from vprsnn_export.network.modules import module_regions, neuron_modules

from .aggregation import count_at_least
from .assignment import count_pair, entry_rows, like_input, sparse_counts


@dataclass(frozen=True)
class ModuleLayout:
    """Which reference places each neuron's module was trained on, and the regularisation (lambda, rho).

    ``regions`` (M, 2) [start, stop) indices into the reference places (``modules.module_regions``);
    ``group`` = n neurons per module; ``hyperactive_share`` = rho; ``outside_weight`` = lambda.
    """

    regions: np.ndarray
    group: int
    hyperactive_share: float
    outside_weight: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "regions", check_regions(self.regions))
        count_at_least("module layout: group", self.group, 1)
        for name in ("hyperactive_share", "outside_weight"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
                raise InvalidValueError(f"module layout: {name} must lie in [0, 1], got {value!r}")

    @property
    def n_neurons(self) -> int:
        return len(self.regions) * self.group


MAX_PLACE_INDEX = 1 << 53


def check_regions(regions: np.ndarray) -> np.ndarray:
    """Regions (M, 2) [start, stop) as int64 when they tile the places 0..stop: integers, non-empty, in order,
    each starting where the last one stopped (no gap, no overlap); InvalidValueError naming ``regions`` otherwise."""
    try:
        values = np.asarray(regions, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidValueError(f"regions must be an (M, 2) array of integers, got {type(regions).__name__}") from None
    if values.ndim != 2 or values.shape[1] != 2 or values.shape[0] == 0:
        raise InvalidValueError(f"regions must be an (M, 2) array of [start, stop) rows, M >= 1, got {values.shape}")
    if not np.all(np.isfinite(values)) or np.any(values != np.round(values)) or np.abs(values).max() > MAX_PLACE_INDEX:
        raise InvalidValueError("regions must hold integer place indices (no fractions, NaN or infinities)")
    starts, stops = values[:, 0].astype(np.int64), values[:, 1].astype(np.int64)
    if starts[0] != 0 or np.any(stops <= starts) or np.any(starts[1:] != stops[:-1]):
        raise InvalidValueError(
            "regions must tile the places from 0 in order: non-empty [start, stop) rows, each starting where the "
            f"last one stopped (no gap, no overlap), got {values.astype(np.int64).tolist()[:6]}"
        )
    return np.stack([starts, stops], axis=1)


def module_layout(
    cfg: Config, n_places: int, hyperactive_share: float | None = None, outside_weight: float | None = None
) -> ModuleLayout:
    """The layout of the ensemble ``cfg`` describes over ``n_places`` reference places (rho and lambda from
    the config unless given)."""
    require_type("cfg", cfg, Config)
    rho = cfg.assignment.hyperactive_share if hyperactive_share is None else hyperactive_share
    lam = cfg.assignment.outside_weight if outside_weight is None else outside_weight
    return ModuleLayout(module_regions(n_places, cfg.train.module_size), cfg.network.n_neurons, float(rho), float(lam))


def ensemble_layout(config: Config, n_places: int) -> ModuleLayout | None:
    """The module layout of an ensemble's config (None for a single network, ``train.module_size`` 0)."""
    return module_layout(config, n_places) if config.train.module_size > 0 else None


def _inside(sr: sparse.csr_array, regions: np.ndarray, group: int) -> np.ndarray:
    """Per stored entry (i, l) of ``sr``: whether l lies in R(i) (``modules.region_mask`` at those entries); the
    regions already checked."""
    shape = (len(regions) * group, int(regions[-1, 1]))
    if shape != sr.shape:
        raise InvalidValueError(
            f"sr has shape {sr.shape} but the module layout describes {shape[0]} neurons x {shape[1]} places"
        )
    return neuron_modules(shape[0], group)[entry_rows(sr)] == np.searchsorted(regions[:, 1], sr.indices, side="right")


def _scaled(sr: sparse.csr_array, factor: np.ndarray) -> sparse.csr_array:
    """``sr`` with each stored entry multiplied by ``factor`` (one per entry), the entries made 0 dropped."""
    out = sparse.csr_array((sr.data * factor, sr.indices.copy(), sr.indptr.copy()), shape=sr.shape)
    out.eliminate_zeros()
    return out


def region_weighting(sr: np.ndarray, regions: np.ndarray, group: int, outside_weight: float) -> np.ndarray:
    """S^R with every response outside the neuron's own region scaled by lambda, shape ``(neurons, places)``.

    .. math:: \\tilde S_{il} = \\begin{cases} S^R_{il} & l \\in R(i) \\\\ \\lambda\\, S^R_{il} & l \\notin R(i) \\end{cases}

    lambda = 0: region-specific assignment (Hussaini et al.); lambda = 1: S^R unchanged. Dense or CSR, as given:
    :func:`regularised_calibration` with rho = 1, which silences no neuron.
    """
    return regularised_calibration(sr, ModuleLayout(regions, group, 1.0, outside_weight))[0]


def outside_involvement(sr: np.ndarray, regions: np.ndarray, group: int) -> np.ndarray:
    """Share of the places outside its module's region that each neuron fires for, shape ``(neurons,)``.

    .. math:: o_i = \\frac{\\#\\{l \\notin R(i) : S^R_{il} > 0\\}}{\\#\\{l \\notin R(i)\\}}

    0 for a neuron whose region covers every place (a single network).
    """
    sr_, regions_ = sparse_counts("sr", sr), check_regions(regions)
    fires_outside = np.bincount(entry_rows(sr_)[~_inside(sr_, regions_, group)], minlength=sr_.shape[0])
    outside = (sr_.shape[1] - (regions_[:, 1] - regions_[:, 0]))[neuron_modules(sr_.shape[0], group)]
    return np.where(outside > 0, fires_outside / np.maximum(outside, 1), 0.0)


def hyperactive_neurons(sr: np.ndarray, layout: ModuleLayout) -> np.ndarray:
    """Boolean mask of the neurons to silence, shape ``(neurons,)``.

    .. math:: \\mathrm{silent}_i = o_i > \\rho

    with :math:`o_i` from :func:`outside_involvement` and :math:`\\rho` = ``layout.hyperactive_share``.
    """
    return outside_involvement(sr, layout.regions, layout.group) > float(layout.hyperactive_share)


def silenced_counts(sq: sparse.csr_array, silent: np.ndarray) -> sparse.csr_array:
    """S^Q without the silent neurons' counts: :math:`S^Q_{\\cdot i} \\leftarrow 0` for every silent i (CSR)."""
    return sq if not silent.any() else _scaled(sq, np.where(silent[sq.indices], 0.0, 1.0))


def regularise(sr: np.ndarray, sq: np.ndarray, layout: ModuleLayout | None) -> tuple[np.ndarray, np.ndarray]:
    """S~ (region-weighted S^R) and S^Q with the hyperactive neurons of ``layout`` silenced
    (both unchanged when ``layout`` is None), each dense or CSR as given.

    .. math:: \\mathrm{silent}_i = o_i > \\rho, \\quad
              o_i = \\frac{\\#\\{l \\notin R(i) : S^R_{il} > 0\\}}{\\#\\{l \\notin R(i)\\}}, \\quad
              \\tilde S_{il} = S^R_{il} \\,(1 \\text{ if } l \\in R(i) \\text{ else } \\lambda)

    Only S^R (reference data) decides; the queries are not looked at.
    """
    require_type("layout", layout, (ModuleLayout, type(None)))
    weighted, silent = calibrated_half(sr, layout)
    return like_input(weighted, sr), like_input(silenced_counts(count_pair(weighted, sq)[1], silent), sq)


def calibrated_half(sr: np.ndarray, layout: ModuleLayout | None) -> tuple[sparse.csr_array, np.ndarray]:
    """S^R as float64 CSR and no neuron silenced, or S~ and the silenced neurons of ``layout``
    (:func:`regularised_calibration`): the query-independent half of a readout."""
    sr_ = sparse_counts("sr", sr)
    return (sr_, np.zeros(sr_.shape[0], dtype=bool)) if layout is None else regularised_calibration(sr_, layout)


def regularised_calibration(sr: np.ndarray, layout: ModuleLayout) -> tuple[np.ndarray, np.ndarray]:
    """S~ (float64: region-weighted, the silenced rows zeroed; dense or CSR as given) and the silenced neurons
    (bool, (neurons,)), the half of :func:`regularise` that needs no query (the ONNX head embeds it)."""
    sr_ = sparse_counts("sr", sr)
    silent = hyperactive_neurons(sr_, layout)
    factor = np.where(_inside(sr_, layout.regions, layout.group), 1.0, layout.outside_weight) * ~silent[entry_rows(sr_)]
    return like_input(_scaled(sr_, factor), sr), silent


@dataclass(frozen=True)
class ModuleAccuracy(JsonDataclass):
    """How the whole-route decisions fare on the queries of one module's region."""

    module: int
    first_place: int  # reference place ids of the region, inclusive
    last_place: int
    n_queries: int
    accuracy: float  # correct decisions / queries of the region
    in_region: float  # decisions that name a place of the region / queries of the region (the right module won)


def module_accuracy(
    pred_index: np.ndarray,
    correct: np.ndarray,
    reference_place_ids: np.ndarray,
    regions: np.ndarray,
    true_index: np.ndarray,
    known: np.ndarray,
) -> list[ModuleAccuracy]:
    """Per module m, over the queries whose true place lies in region m (a query of no reference place is left out):

    .. math:: \\mathrm{acc}_m = \\frac{\\#\\{q : \\mathrm{correct}_q\\}}{\\#\\{q\\}}, \\qquad
              \\mathrm{in}_m = \\frac{\\#\\{q : \\hat l_q \\in R_m\\}}{\\#\\{q\\}}

    ``pred_index`` are predicted indices into the reference places (-1: no match), ``correct`` the decisions'
    correctness; ``true_index`` and ``known`` each query's true reference index and whether it has one, by the
    truth that judged it (:meth:`vprsnn_export.data.truth.Truth.first_true`), all arrays (the regions checked). One
    ``bincount`` per quantity.
    """
    n_modules = len(regions)
    true_module = np.searchsorted(regions[:, 1], true_index, side="right")
    pred_module = np.where(pred_index >= 0, np.searchsorted(regions[:, 1], np.maximum(pred_index, 0), side="right"), -1)
    modules = true_module[known]
    totals = np.bincount(modules, minlength=n_modules)
    hits = np.bincount(modules, weights=correct[known], minlength=n_modules)
    inside = np.bincount(modules, weights=(pred_module == true_module)[known], minlength=n_modules)
    share, routed = np.divide([hits, inside], totals, out=np.zeros((2, n_modules)), where=totals > 0)
    first, last = reference_place_ids[regions[:, 0]].tolist(), reference_place_ids[regions[:, 1] - 1].tolist()
    return [
        ModuleAccuracy(m, first[m], last[m], int(totals[m]), float(share[m]), float(routed[m]))
        for m in range(n_modules)
    ]
