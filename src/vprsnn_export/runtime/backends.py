"""The backends a network runs on, by name (localize's ``--backend``): a module of its own, so that the
command line lists them without importing torch."""

from __future__ import annotations

#: ``auto``: float for a checkpoint, integer for a fixed-point model, onnx when an ONNX graph is given.
BACKENDS = ("auto", "float", "integer", "onnx")

__all__ = ["BACKENDS"]
