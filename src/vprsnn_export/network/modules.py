"""Modular ensembles: one compact network per region of consecutive places (Hussaini et al.).

``train.module_size = P`` (0: one network for every selected place) cuts the reference
places, in their order, into regions of P consecutive places; module m is trained on
region m alone. The ensemble is stored as **one** network whose neurons are the modules'
neurons side by side: module m owns neurons [m n, (m + 1) n) with n = ``network.n_neurons``,
so the weights are (inputs, M n), the thresholds (M n,) and S^R (M n, places). Training
applies the hard WTA within each module (one winner per module per step: each module learns
its region). Calibration, queries and every deployed implementation apply it within the WTA
group of ``network.wta_scope``: the whole ensemble (the default; modules compete, so a query's
spikes go to the modules that match it) or each module. With one module both are the single
network's WTA, unchanged.

    M        = ceil(places / P)                 (1 when P = 0)
    region_m = places [m P, min((m + 1) P, places))
    module(j) = j // n
"""

from __future__ import annotations

import numpy as np

from ..arguments import require_integer
from ..config import Config
from ..errors import InvalidValueError

MAX_COUNT = 1 << 53  # places and module sizes: exact in float64, far beyond any route
MAX_MODULES = 1 << 20  # modules of one ensemble: beyond any route, before the (M, 2) regions exhaust memory


def module_count(n_places: int, module_size: int) -> int:
    """M = ceil(places / P); 1 when P = 0 (one network) or when there are no places yet."""
    n_places = require_integer("n_places", n_places, 0, MAX_COUNT)
    module_size = require_integer("module_size", module_size, 0, MAX_COUNT)
    return 1 if module_size <= 0 or n_places <= 0 else -(-n_places // module_size)


def module_regions(n_places: int, module_size: int) -> np.ndarray:
    """(M, 2) int64 [start, stop) indices into the reference places: region m = [m P, min((m + 1) P, places))."""
    n_places = require_integer("n_places", n_places, 0, MAX_COUNT)
    module_size = require_integer("module_size", module_size, 0, MAX_COUNT)
    if module_size <= 0:
        return np.array([[0, n_places]], dtype=np.int64)
    if module_count(n_places, module_size) > MAX_MODULES:
        raise InvalidValueError(
            f"{n_places} places in modules of {module_size} make more than {MAX_MODULES} modules "
            "(train.module_size sets the places per module)"
        )
    starts = np.arange(0, n_places, module_size, dtype=np.int64)
    return np.stack([starts, np.minimum(starts + module_size, n_places)], axis=1)


def ensemble_neurons(cfg: Config, n_places: int) -> int:
    """Neurons of the whole ensemble: M n."""
    return module_count(n_places, cfg.train.module_size) * cfg.network.n_neurons


def neuron_modules(n_total: int, group: int) -> np.ndarray:
    """module(j) = j // n for every neuron j of an ensemble of ``n_total`` neurons in WTA groups of n."""
    return np.arange(n_total, dtype=np.int64) // group


def region_mask(regions: np.ndarray, group: int) -> np.ndarray:
    """(M n, places) bool: True where place l lies in the region of neuron j's module."""
    place_module = np.searchsorted(regions[:, 1], np.arange(int(regions[-1, 1])), side="right")
    return neuron_modules(len(regions) * group, group)[:, None] == place_module[None, :]
