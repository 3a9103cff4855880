"""The public API: everything a notebook needs, importable as ``import vprsnn_export as vx``.

The chain of the command line, as library calls (docs/examples/quickstart.py runs it):

    data = vx.load_dataset("synthetic:24", ["summer", "winter"], vx.Config().preprocess)
    ckpt = vx.train_and_calibrate(data, ["summer"], cfg)                    # STDP + calibration S^R
    cfg.replace(**{"train.module_size": 100})                                # a whole route: modules side by side
    vx.evaluate_float(ckpt, images, place_ids, "winter", readout)           # Standard/Weighted/W+Prob, k frames
    model = vx.deploy(ckpt, sha, bits=4, reference_images=...)              # quantise + calibrate on integers
    vx.export_and_check(vx.ExportSource.of(model, sha), model, ("nir", "onnx", "loihi"), "deploy/")
    backends = [vx.IntegerNetwork(model), vx.ReferenceStepper(model), vx.OnnxBackend(path)]
    run = vx.verify_checkpoint(ckpt, sha, images, place_ids, "winter", vx.VerifyOptions(readout))
"""

from __future__ import annotations

from .checkpoint import Checkpoint, checkpoint_sha256, load_checkpoint, save_checkpoint
from .cluster import Cluster, parse_cluster
from .config import Config
from .dataset import Dataset, load_dataset, select_places
from .dynamics import FloatNetwork
from .encoding import calibration_spikes, query_spikes
from .errors import DataError, InvalidValueError, ModelFileError, VprError
from .export.model import FixedPointModel, load_fixed_point, save_fixed_point
from .export.quantize import quantize_checkpoint
from .modules import module_count, module_regions
from .readout.aggregation import aggregate, estimate_velocity, smooth_velocity
from .readout.assignment import decide, strategy_scores
from .readout.baseline import sad_distances, sad_distribution
from .readout.metrics import pr_metrics
from .readout.regions import ModuleLayout, module_layout, regularise
from .runs import Backend, SpikeRun
from .runtime.conformance import compare_backends, cross_implementation
from .runtime.deployment import deploy, recalibrate
from .runtime.evaluation import Evaluation, ReadoutOptions, evaluate_fixed_point, evaluate_float, readout_rows
from .runtime.exporting import ExportResult, ExportSource, export_and_check, load_source, read_export
from .runtime.report import write_report
from .runtime.results import ConformanceResult, VerifiedRun, VerifyReport
from .runtime.verify import VerifyOptions, build_report, verify_checkpoint
from .targets.intsim import IntegerNetwork
from .targets.loihi_target import read_loihi_model, write_loihi
from .targets.nir_target import apply_readout_rule, read_nir, write_nir
from .targets.onnx_target import OnnxBackend, write_onnx
from .targets.reference_stepper import ReferenceStepper
from .threads import set_threads
from .trainer.batched import train_modules
from .trainer.calibrate import calibrate
from .trainer.pipeline import train_and_calibrate
from .trainer.sharded import train_modules_on_cluster
from .trainer.train import train_network
from .version import __version__

__all__ = [
    "Backend",
    "Checkpoint",
    "Cluster",
    "Config",
    "ConformanceResult",
    "DataError",
    "Dataset",
    "Evaluation",
    "ExportResult",
    "ExportSource",
    "FixedPointModel",
    "FloatNetwork",
    "IntegerNetwork",
    "InvalidValueError",
    "ModelFileError",
    "ModuleLayout",
    "OnnxBackend",
    "ReadoutOptions",
    "ReferenceStepper",
    "SpikeRun",
    "VerifiedRun",
    "VerifyOptions",
    "VerifyReport",
    "VprError",
    "__version__",
    "aggregate",
    "apply_readout_rule",
    "build_report",
    "calibrate",
    "calibration_spikes",
    "compare_backends",
    "cross_implementation",
    "checkpoint_sha256",
    "decide",
    "deploy",
    "estimate_velocity",
    "evaluate_fixed_point",
    "evaluate_float",
    "export_and_check",
    "load_checkpoint",
    "module_count",
    "module_layout",
    "module_regions",
    "load_dataset",
    "load_fixed_point",
    "load_source",
    "parse_cluster",
    "pr_metrics",
    "quantize_checkpoint",
    "query_spikes",
    "read_export",
    "read_loihi_model",
    "read_nir",
    "regularise",
    "readout_rows",
    "recalibrate",
    "sad_distances",
    "sad_distribution",
    "save_checkpoint",
    "save_fixed_point",
    "select_places",
    "set_threads",
    "smooth_velocity",
    "strategy_scores",
    "train_and_calibrate",
    "train_modules",
    "train_modules_on_cluster",
    "train_network",
    "verify_checkpoint",
    "write_loihi",
    "write_nir",
    "write_onnx",
    "write_report",
]
