"""Float inference of a trained network on query presentations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from vprsnn_export.config import Config
from vprsnn_export.dynamics import NetworkRun, run_network
from vprsnn_export.encoding import encode_presentations

STREAM_QUERY = "query"


def query_spikes(images: np.ndarray, place_ids: np.ndarray, traversal: str, cfg: Config) -> torch.Tensor:
    """The query presentations (N, T, inputs) uint8; every backend is fed exactly these."""
    return encode_presentations(images, place_ids, cfg.encoder, seed=cfg.seed, stream=STREAM_QUERY, traversal=traversal)


@dataclass
class FloatNetwork:
    """The float reference network: float32 weights and thresholds on a device."""

    weights: torch.Tensor
    thresholds: torch.Tensor
    cfg: Config

    @classmethod
    def from_arrays(
        cls, weights: np.ndarray, thresholds: np.ndarray, cfg: Config, device: torch.device
    ) -> FloatNetwork:
        return cls(
            torch.as_tensor(weights, dtype=torch.float32).to(device),
            torch.as_tensor(thresholds, dtype=torch.float32).to(device),
            cfg,
        )

    def run(self, spikes: torch.Tensor, *, record: bool = False, state_isolation: bool | None = None) -> NetworkRun:
        isolation = self.cfg.network.state_isolation if state_isolation is None else state_isolation
        return run_network(
            spikes,
            self.weights,
            self.thresholds,
            beta=self.cfg.network.beta,
            wta=self.cfg.network.wta,
            state_isolation=isolation,
            record=record,
        )

    def counts(self, spikes: torch.Tensor) -> torch.Tensor:
        return self.run(spikes).counts
