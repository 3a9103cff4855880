"""`vprsnn-export export` as a library: read a model, write NIR / Loihi-style / ONNX, check the files.

A model file is a float checkpoint or a fixed-point model (:func:`load_source`, by its container's ``format``).
NIR takes either; the integer targets (Loihi-style, ONNX) need a fixed-point model, which a checkpoint gets only on
request (:func:`integer_model`). The model read and the targets written: :mod:`.source`; every file read back and
run beside the project's simulators (conformance, a metadata-blind NIR consumer, the consumer gate): :mod:`.checks`;
the deploy folder (export.json, :func:`export_and_check`, :func:`read_export`): :mod:`.folder`.
"""

from .folder import ExportResult, export_and_check, read_export
from .source import ExportSource, load_source

__all__ = ["ExportResult", "ExportSource", "export_and_check", "load_source", "read_export"]
