"""An experiment's settings (size, data, seeds) and where its pages go: what the command line needs
to list the options, without the torch the experiments themselves import."""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from vprsnn_export.cluster import Cluster
from vprsnn_export.config import Config, preset

NORDLAND = Path("../shared/data/nordland_64x32_summer_winter")  # relative to the repository root, where experiments run
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
