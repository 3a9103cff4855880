"""Choosing the torch device: ``auto`` takes a GPU when one is present."""

from __future__ import annotations

import torch

from .errors import InvalidValueError

DEVICE_CHOICES = ("auto", "cpu", "cuda")


def resolve_device(name: str) -> torch.device:
    if name not in DEVICE_CHOICES:
        raise InvalidValueError(f"--device must be one of {', '.join(DEVICE_CHOICES)}, got {name!r}")
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise InvalidValueError("--device cuda was requested but torch sees no CUDA GPU")
    return torch.device(name)
