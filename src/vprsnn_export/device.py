"""Choosing the torch device: ``auto`` takes a GPU when one is present."""

from __future__ import annotations

import torch

from .arguments import require_choice
from .errors import InvalidValueError

DEVICE_CHOICES = ("auto", "cpu", "cuda")


def resolve_device(name: str) -> torch.device:
    if require_choice("--device", name, DEVICE_CHOICES) == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    check_device("--device", name)  # cuda refused without a GPU
    return torch.device(name)


def check_device(name: str, value: object) -> torch.device | None:
    """``value`` as a torch device (a torch.device or a name such as "cpu"; None stays None); InvalidValueError
    naming the argument ``name`` for anything else, or for a CUDA device when torch sees no GPU."""
    if value is None or isinstance(value, torch.device):
        device = value
    elif isinstance(value, str):
        try:
            device = torch.device(value)
        except (RuntimeError, ValueError):
            raise InvalidValueError(f"{name} must be a torch device such as 'cpu' or 'cuda', got {value!r}") from None
    else:
        raise InvalidValueError(f"{name} must be a torch.device (or None), got {type(value).__name__}")
    if device is not None and device.type == "cuda" and not torch.cuda.is_available():
        raise InvalidValueError(f"{name} is {device} but torch sees no CUDA GPU")
    return device
