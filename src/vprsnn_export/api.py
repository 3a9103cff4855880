"""The public API: everything a notebook needs, importable as ``import vprsnn_export as vx``.

docs/examples/quickstart.py runs the chain of the command line as library calls: ``vx.load_dataset``,
``vx.train_and_calibrate``, ``vx.evaluate_float``, ``vx.deploy``, ``vx.export_and_check``, ``vx.verify_checkpoint``,
``vx.Localizer``. The extension points are registries (docs/architecture.md): ``vx.TARGETS``, ``vx.STRATEGIES``,
``vx.CHANNELS``, ``vx.VELOCITY_ESTIMATES``; ``vx.TARGETS.register(vx.Target(...))`` adds one.
"""

# ruff: noqa: F401  (every import is a re-export: __all__ below lists them all)
from .cluster import Cluster, parse_cluster
from .config import Config
from .data.dataset import Dataset, load_dataset, select_places
from .data.encoding import calibration_spikes, query_spikes
from .data.frames import iter_frames
from .data.preprocess import CHANNELS, Channel
from .data.truth import EXACT, GroundTruth, MatchWindow, Query, Truth
from .errors import DataError, InvalidValueError, ModelFileError, VprError
from .export.model import FixedPointModel, load_fixed_point, save_fixed_point
from .export.quantize import QuantiseOptions, quantize_checkpoint
from .io.checkpoint import Checkpoint, checkpoint_sha256, load_checkpoint, save_checkpoint
from .network.dynamics import FloatNetwork
from .network.modules import module_count, module_regions
from .network.runs import Backend, SpikeRun
from .readout.aggregation import aggregate, estimate_velocity, smooth_velocity
from .readout.baseline import sad_distances, sad_distribution
from .readout.metrics import pr_metrics
from .readout.regions import ModuleLayout, module_layout, regularise
from .readout.scoring import Readout, readout_rows
from .readout.sequence import SequenceOptions
from .readout.strategies import STRATEGIES, Strategy, decide, strategy_scores
from .readout.velocity import VELOCITY_ESTIMATES, VelocityEstimator
from .resources import memory_limit, set_memory_limit
from .runtime.conformance import compare_backends, cross_implementation
from .runtime.deployment import deploy, recalibrate
from .runtime.evaluation import Evaluation, evaluate_fixed_point, evaluate_float
from .runtime.exporting import ExportResult, ExportSource, export_and_check, load_source, read_export
from .runtime.localize import Localizer, OperatingPoint, operating_point
from .runtime.predictions import Predictions, network_predictions
from .runtime.report import write_report
from .runtime.results import ConformanceResult, VerifiedRun, VerifyReport
from .runtime.verify import Runtime, VerifiedNetwork, VerifyOptions, build_report, verify_checkpoint
from .targets.intsim import IntegerNetwork
from .targets.loihi_target import read_loihi_model, write_loihi
from .targets.nir_read import read_nir
from .targets.nir_target import apply_readout_rule, write_nir
from .targets.onnx_session import OnnxBackend
from .targets.onnx_target import write_onnx
from .targets.reference_stepper import ReferenceStepper
from .targets.registry import TARGETS, Target
from .threads import set_threads
from .trainer.adaptation import MECHANISMS, Adaptation, adapt_config
from .trainer.batched import train_modules
from .trainer.calibrate import calibrate
from .trainer.pipeline import train_and_calibrate
from .trainer.sharded import train_modules_on_cluster
from .trainer.train import train_network
from .version import __version__

#: Every name imported above (and the version): the import list is the public API.
__all__ = sorted(name for name in globals() if not name.startswith("_")) + ["__version__"]
