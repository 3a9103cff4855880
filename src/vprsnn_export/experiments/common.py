"""What every experiment shares: its data, its size (quick or full), seeds and summaries."""

from __future__ import annotations

import platform
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from vprsnn_export import __version__
from vprsnn_export.config import Config
from vprsnn_export.dataset import Dataset, load_dataset

NORDLAND = Path("../shared/data/nordland_64x32_summer_winter")  # relative to the repository root, where experiments run


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

    @classmethod
    def quick_settings(cls, **changes) -> "Settings":
        base = dict(
            quick=True, data="synthetic:40", subset=None, consecutive="0:40", seeds=(1, 2),
            overrides={"encoder.timesteps": 60, "train.epochs": 3, "network.n_neurons": 100},
        )
        base.update(changes)
        return cls(**base)

    def config(self, seed: int, **extra) -> Config:
        return Config().replace(**{**self.overrides, "seed": seed, **extra})


def load(settings: Settings, selection: str, cfg: Config) -> Dataset:
    """``selection`` is "subset" (the 100-place subset) or "consecutive" (a run of places)."""
    traversals = [settings.reference, settings.query]
    if selection == "subset" and settings.subset:
        return load_dataset(settings.data, traversals, cfg.preprocess, subset=settings.subset)
    return load_dataset(settings.data, traversals, cfg.preprocess, places=settings.consecutive)


def mean_std(values) -> dict:
    array = np.asarray(list(values), dtype=np.float64)
    return {"mean": float(array.mean()), "std": float(array.std(ddof=1)) if len(array) > 1 else 0.0, "n": len(array)}


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


def pct(summary: dict) -> str:
    return f"{100 * summary['mean']:.1f} ± {100 * summary['std']:.1f}"
