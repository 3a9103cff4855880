"""`vprsnn-export export` as a library: read a model, write NIR / Loihi-style / ONNX, check the files.

A model file is a float checkpoint (``train``) or a fixed-point model (``quantize``),
told apart by its container's ``format`` field (:func:`load_source`). NIR takes either;
the Loihi description and ONNX are integer targets and need a fixed-point model, which
a float checkpoint gets only on request (:func:`integer_model`: per-neuron max-abs
scales, the float calibration kept). :func:`check_exports` reads every written file
back and runs it beside the project's own simulators with the conformance harness of
:mod:`runtime.conformance` (exact), plus the measured agreement of a metadata-blind NIR
consumer (a measurement), and the NIR consumer gate (:mod:`runtime.consumer_gate`): every
installed float consumer must decide as the network does within the file's stated tolerance.

The model read and the targets written: :mod:`.source`; every file read back and run:
:mod:`.checks`; the deploy folder (export.json, :func:`export_and_check`, :func:`read_export`):
:mod:`.folder`.
"""

from .folder import ExportResult, export_and_check, read_export
from .source import ExportSource, load_source

__all__ = ["ExportResult", "ExportSource", "export_and_check", "load_source", "read_export"]
