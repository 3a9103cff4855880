"""An experiment's settings (size, data, seeds) and where its pages go: what the command line needs
to list the options, without the torch the experiments themselves import."""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from vprsnn_export.cluster import Cluster
from vprsnn_export.config import Config, preset
from vprsnn_export.data.folders import is_folder_dataset
from vprsnn_export.errors import DataError

#: The Nordland data folder as this repository's checkout keeps it, relative to the repository root: the
#: default of ``experiment --data`` (after $VPRSNN_DATA), so only a run from the repository root finds it.
NORDLAND = Path("../shared/data/nordland_64x32_summer_winter")
DATA_ENV = "VPRSNN_DATA"
MANIFEST = "places.csv"  # a data folder's place manifest
SUBSET = "subset_100_places.csv"  # and its 100-place subset (the paper's tables)
DOCS_RESULTS = "docs/results"  # the committed pages, written only by ``experiment NAME --update-docs``


@dataclass(frozen=True)
class Variant:
    """One named point of a sweep grid (``--grid NAME=PRESET[,KEY=VALUE...]``): a preset plus config overrides."""

    name: str
    preset: str = "paper"
    overrides: dict = field(default_factory=dict)  # dotted config overrides, applied after the settings' own


@dataclass(frozen=True)
class Settings:
    """An experiment's size and data. ``quick`` runs on the synthetic route in CI."""

    quick: bool = False
    data: str = str(NORDLAND / "places.csv")
    subset: str | None = str(NORDLAND / "subset_100_places.csv")
    consecutive: str = "1000:100"
    reference: str = "summer"
    query: str = "winter"
    seeds: tuple[int, ...] = (1, 2, 3, 4, 5)
    device: str = "cpu"
    progress: bool = True
    overrides: dict = field(default_factory=dict)  # dotted config overrides
    grid: tuple[Variant, ...] = ()  # experiment sweep's variants (empty: its default grid)
    preset: str = "paper"  # the paper's experiments reproduce the paper's configuration
    module_sizes: tuple[int, ...] = ()  # experiment route's module sizes (empty: its default sizes)
    cluster: Cluster | None = None  # train every network's modules on this Ray cluster (--cluster)
    checkpoints: tuple[str, ...] = ()  # experiment cost: measure these trained checkpoints (--checkpoint)

    @classmethod
    def quick_settings(cls, **changes: Any) -> Settings:
        """The tiny synthetic size the test suite runs (``--quick``), with ``changes`` applied."""
        quick = cls(
            quick=True,
            data="synthetic:24",
            subset=None,
            consecutive="0:24",
            seeds=(1, 2),
            overrides={"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 64},
        )
        return replace(quick, **changes)

    def config(self, seed: int, **extra) -> Config:
        return preset(self.preset).replace(**{**self.overrides, "seed": seed, **extra})


def results_dir() -> Path:
    """Where ``experiment NAME`` writes by default: $VPRSNN_RESULTS, else ~/.cache/vprsnn-export/results
    (outside the repository: only ``--update-docs`` writes the committed docs/results)."""
    return Path(os.environ.get("VPRSNN_RESULTS", Path.home() / ".cache" / "vprsnn-export" / "results"))


def data_settings(given: str | None) -> dict[str, str | None]:
    """The ``data`` and ``subset`` of :class:`Settings` for ``experiment --data``: a data folder gives its
    :data:`MANIFEST` and its :data:`SUBSET` (when present), a folder of traversal subfolders without one gives
    itself (its ground truth checked by :func:`experiments.common.load`); a place manifest (or ``synthetic:N``) gives itself
    and no subset. None: $VPRSNN_DATA, else :data:`NORDLAND`. DataError (one line) when nothing is there."""
    if given is not None and not given.strip():
        raise DataError("--data: an empty path")
    chosen = given if given is not None else os.environ.get(DATA_ENV) or None
    if chosen is not None and chosen.startswith("synthetic:"):
        return {"data": chosen, "subset": None}
    path = Path(chosen) if chosen is not None else NORDLAND
    if path.is_dir() and not (path / MANIFEST).is_file() and is_folder_dataset(path):
        return {"data": str(path), "subset": None}  # one traversal per subfolder (docs/data.md)
    if path.is_dir():
        subset = path / SUBSET
        return {"data": str(path / MANIFEST), "subset": str(subset) if subset.is_file() else None}
    if path.is_file():
        return {"data": str(path), "subset": None}
    if given is not None:
        where = "--data"
    elif chosen is not None:
        where = f"${DATA_ENV}"
    else:
        where = f"the default data folder (relative to the repository root: run there, or give --data DIR or set ${DATA_ENV})"
    raise DataError(f"no data folder or place manifest at {path}: {where}")
