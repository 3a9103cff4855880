"""The registries: an unknown name is one clear error everywhere, and a new entry flows through with one line.

The toy target (a fixed-point model saved as .npz) and the toy strategy (every neuron votes
for each place it fired for) are registered here with one line each, as docs/architecture.md
shows, and then seen in the files `export` writes, the checks it runs, `verify`'s
cross-implementation checks, the readout rows and the report's tables.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from vprsnn_export.cli import main
from vprsnn_export.config import Config, PreprocessConfig
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.encoding import encode, query_spikes
from vprsnn_export.data.preprocess import CHANNELS, Channel, normalise_resized
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.errors import EXIT_BAD_INPUT, InvalidValueError
from vprsnn_export.export.model import FixedPointModel, load_fixed_point, save_fixed_point
from vprsnn_export.export.quantize import QuantiseOptions, quantize_checkpoint
from vprsnn_export.io.checkpoint import checkpoint_sha256, load_checkpoint
from vprsnn_export.readout.aggregation import aggregate
from vprsnn_export.readout.assignment import share_decision
from vprsnn_export.readout.scoring import Readout
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.readout.strategies import STRATEGIES, Strategy, decide, strategy_scores
from vprsnn_export.registry import Registry
from vprsnn_export.runtime.backends import BACKENDS, BackendKind, choose_backend
from vprsnn_export.runtime.conformance import cross_implementation, read_back, write_targets
from vprsnn_export.runtime.evaluation import evaluate_fixed_point, evaluate_float
from vprsnn_export.runtime.exporting import ExportSource, export_and_check
from vprsnn_export.runtime.exporting.source import export_all
from vprsnn_export.runtime.localize import Localizer
from vprsnn_export.runtime.report import write_report
from vprsnn_export.runtime.report.labels import row_label
from vprsnn_export.runtime.verify import VerifiedNetwork, VerifyOptions, build_report, verify_checkpoint
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.targets.registry import TARGETS, Network, Target, WriteOptions, integer

# ---------------------------------------------------------------------------- the toy entries


def write_npz(network: Network, path: Path, options: WriteOptions) -> list[Path]:
    """The toy target's writer: the project's own fixed-point container."""
    return [save_fixed_point(path, integer(network, "npz"))]


def npz_statement(network: Network, model: FixedPointModel | None, options: WriteOptions) -> str:
    return "vprsnn-export's load_fixed_point reads the model exactly."


def any_place_scores(sr: np.ndarray, sq: np.ndarray, gamma: float) -> np.ndarray:
    """The toy strategy: each neuron votes for every place it fired for, Score = S^Q [S^R > 0] (CSR in, dense out)."""
    return (sq @ (sr > 0).astype(np.float64)).toarray()


def pair_channels(resized: np.ndarray, cfg: PreprocessConfig) -> np.ndarray:
    """The toy channels: the image and its negative side by side, (N, S, 2 S)."""
    image = resized.astype(np.float32) / 255
    return np.concatenate([image, 1 - image], axis=2)


@pytest.fixture
def toy_target():
    TARGETS.register(
        Target("npz", "npz", "npz read back", True, "model.npz", write_npz, load_fixed_point, npz_statement)
    )
    yield TARGETS.get("npz")
    TARGETS.unregister("npz")


@pytest.fixture
def toy_strategy():
    STRATEGIES.register(Strategy("anyplace", "Any place", any_place_scores, share_decision, needs_gamma=False))
    yield STRATEGIES.get("anyplace")
    STRATEGIES.unregister("anyplace")


@pytest.fixture
def toy_channel_entry():
    CHANNELS.register(Channel("pair", 2, pair_channels, "image and negative"))
    yield CHANNELS.get("pair")
    CHANNELS.unregister("pair")


@pytest.fixture
def spikes_of():
    def spikes(model: FixedPointModel, n: int = 6) -> torch.Tensor:
        rng = np.random.default_rng(1)
        images = rng.random((n, model.config.network.n_inputs)).astype(np.float32)
        return encode(images, list(range(n)), model.config.encoder)

    return spikes


# ---------------------------------------------------------------------------- the helper


def test_a_registry_keeps_order_and_names_the_known_entries_on_an_unknown_one():
    registry: Registry[Channel] = Registry("colour")
    registry.register(Channel("red", 1, pair_channels, "r"))
    registry.register(Channel("blue", 1, pair_channels, "b"))
    assert registry.names() == ("red", "blue") and list(registry) == ["red", "blue"] and len(registry) == 2
    assert "red" in registry and "green" not in registry
    with pytest.raises(InvalidValueError, match="colour: unknown 'green'; choose from red, blue"):
        registry.get("green")
    with pytest.raises(ValueError, match="registered already"):
        registry.register(Channel("red", 1, pair_channels, "again"))
    assert registry.parse_list("BLUE, red,,blue", "--colours") == ("blue", "red")
    assert registry.parse_list("none", "--colours", allow_none=True) == ()
    for raw in ("", "green", "red,green", "none"):
        with pytest.raises(InvalidValueError, match="--colours expects some of red, blue"):
            registry.parse_list(raw, "--colours")
    assert registry.unregister("red").name == "red" and registry.names() == ("blue",)


# ---------------------------------------------------------------------------- unknown names


def test_an_unknown_target_is_an_error_everywhere(make_model, tmp_path):
    model = make_model(np.random.default_rng(0))
    source = ExportSource.of(model, "ab" * 32)
    calls = [
        lambda: TARGETS.parse_list("onnx,tflite", "--targets", allow_none=True),
        lambda: TARGETS.parse_list("tflite", "--to"),
        lambda: read_back("tflite", tmp_path / "model.nir", model),  # was: the Loihi reader
        lambda: TARGETS.get("tflite").reader_path([tmp_path / "x"]),
        lambda: write_targets(model, tmp_path, ("nir", "tflite")),
        lambda: export_all(source, model, ("tflite",), tmp_path),
        lambda: TARGETS.get("tflite"),
    ]
    for call in calls:
        with pytest.raises(InvalidValueError, match="tflite"):
            call()
    assert list(tmp_path.iterdir()) == []  # nothing written before the error


def test_an_unknown_strategy_rule_estimate_or_channel_is_an_error_everywhere():
    sr, sq = np.ones((3, 2)), np.ones((4, 3))
    prob = np.full((4, 2), 0.5)
    calls = {
        "strategy": [lambda: decide(prob, "argmax"), lambda: strategy_scores(sr, sq, "argmax", 0.5)],
        "aggregation rule": [
            lambda: aggregate(prob, 2, 1.0, rule="argmax"),
            lambda: SequenceOptions(rule="argmax").aggregate(prob, 2),
        ],
        "velocity estimate": [
            lambda: SequenceOptions(velocity_candidates=(1.0,), velocity_estimate="argmax").aggregate(prob, 2)
        ],
        "config.preprocess.channels": [
            lambda: Config().replace(**{"preprocess.channels": "argmax"}),
            lambda: normalise_resized(np.zeros((1, 4, 4), np.uint8), PreprocessConfig(channels="argmax")),
            lambda: PreprocessConfig(channels="argmax").n_inputs,
        ],
    }
    for kind, functions in calls.items():
        for call in functions:
            with pytest.raises(InvalidValueError, match=f"{kind}.*argmax"):
                call()


@pytest.mark.parametrize(
    "argv",
    [
        ["export", "missing.npz", "--out", "x", "--to", "tflite"],
        ["evaluate", "missing.npz", "--query", "winter", "--rule", "argmax"],
        ["evaluate", "missing.npz", "--query", "winter", "--velocity-estimate", "argmax"],
    ],
)
def test_an_unknown_name_on_the_command_line_exits_2(argv, capsys):
    assert main(argv) == EXIT_BAD_INPUT
    assert argv[-1] in capsys.readouterr().err


def test_the_cli_and_the_library_share_the_velocity_estimate_default(capsys):
    assert main(["evaluate", "--help"]) == 0
    assert f"(default {SequenceOptions().velocity_estimate})" in " ".join(capsys.readouterr().out.split())


# ---------------------------------------------------------------------------- toy entries flow through


def test_a_toy_target_is_exported_read_back_and_checked(toy_target, make_model, spikes_of, tmp_path):
    model = make_model(np.random.default_rng(0))
    assert TARGETS.parse_list("npz,nir", "--to") == ("npz", "nir") and "npz" in TARGETS.parse_list(
        "npz", "--targets", allow_none=True
    )
    source = ExportSource.of(model, "ab" * 32)
    result = export_and_check(source, model, ("npz", "onnx"), tmp_path / "deploy", spikes=spikes_of(model))
    assert list(result.files) == ["onnx", "npz"]  # the registry's order
    np.testing.assert_array_equal(load_fixed_point(result.written("npz")).weight_mantissa, model.weight_mantissa)
    assert result.consumers["npz"] == npz_statement(model, model, WriteOptions())
    assert result.checks is not None and result.passed
    npz_rows = [row for row in result.checks.rows if row.target == "npz"]
    assert npz_rows and all(row.ok for row in npz_rows)
    cross = cross_implementation(model, spikes_of(model), folder=tmp_path / "cross", targets=("npz",))
    assert cross.passed and set(cross.files) == {"npz"}
    assert any(c.check.startswith("npz read back: weight_mantissa") for c in cross.comparisons)
    assert any(c.b == "npz model on the simulator" for c in cross.comparisons)


def test_a_toy_strategy_gives_readout_rows_and_report_titles(toy_strategy, toy_target, tmp_path, tiny_checkpoint):
    sr = np.array([[3, 0], [0, 2], [1, 1]])
    sq = np.array([[2, 0, 0], [0, 0, 1]])
    rows = Readout(sr, 0.5).rows(sq, np.array([0, 1]), np.array([0, 1]))
    assert [r.strategy for r in rows] == ["standard", "weighted", "wprob", "anyplace"]
    assert rows[-1].accuracy == 0.5  # query 1's one spike votes for both places: a tie to place 0
    assert row_label("anyplace", 1) == "Any place k=1"

    path = tiny_checkpoint  # train --data synthetic:8 --timesteps 20 --epochs 1 --neurons 16 (tests/conftest.py)
    ckpt = load_checkpoint(path)
    data = load_dataset("synthetic:8", ["summer", "winter"], ckpt.config.preprocess)
    options = VerifyOptions(readout=SequenceOptions(), bits=(4,), targets=("npz",), reference_queries=0)
    query = data.query("winter", ["summer"])
    network = VerifiedNetwork(ckpt, checkpoint_sha256(path), {"summer": data.traversal("summer")})
    run = verify_checkpoint(network, query, options)
    assert "anyplace" in run.bits[0].decision_level.top1_agreement
    assert {c.check.split(":")[0] for c in run.bits[0].cross_implementation.comparisons} == {"npz read back"}
    write_report(build_report([run], {**options.to_dict(ckpt.config), "query": "winter"}), tmp_path / "report")
    markdown = (tmp_path / "report" / "report.md").read_text()
    assert "Any place k=1" in markdown and "top-1 Any place %" in markdown


def test_a_toy_channel_sets_the_inputs(toy_channel_entry):
    cfg = Config().replace(**{"preprocess.channels": "pair", "network.n_inputs": 2 * 28 * 28})
    assert cfg.preprocess.n_channels == 2 and cfg.preprocess.n_inputs == cfg.network.n_inputs
    with pytest.raises(InvalidValueError, match="must equal 2 channel"):
        Config().replace(**{"preprocess.channels": "pair", "network.n_inputs": 28 * 28})
    images = np.random.default_rng(0).integers(0, 256, (3, 28, 28), dtype=np.uint8)
    out = normalise_resized(images, cfg.preprocess)
    assert out.shape == (3, cfg.network.n_inputs)
    np.testing.assert_allclose(out[:, :28] + out[:, 28:56], 1.0, atol=1e-6)  # row 0: the image, then its negative


TOY_OPENED: list[bool] = []  # the progress flag of each toy backend opened


def open_toy(network, path, device, threads, progress):
    TOY_OPENED.append(progress)
    return IntegerNetwork(network, device, progress=progress)


def test_a_toy_backend_is_one_registry_line_and_selectable(tmp_path, capsys):
    """Issue 33: a new backend is one function and one BACKENDS.register line; localize (the library and
    --backend) and evaluate/simulate's library (``backend=``) find it through the registry and decide as the
    integer simulator it wraps."""
    BACKENDS.register(BackendKind("toy", FixedPointModel, open_toy, "a toy", needs=None))
    try:
        path = tmp_path / "net.npz"
        train = ["train", "--data", "synthetic:8", "--reference", "summer", "--out", str(path), "--quiet"]
        assert main([*train, "--timesteps", "20", "--epochs", "1", "--neurons", "16"]) == 0
        model = quantize_checkpoint(load_checkpoint(path), checkpoint_sha256(path), 4, QuantiseOptions())
        assert choose_backend(model, "toy").name == "toy"
        frames = synthetic_route(8, ("winter",))["winter"]
        toy = Localizer(model, backend="toy", options=SequenceOptions(ks=(3,)))
        plain = Localizer(model, options=SequenceOptions(ks=(3,)))
        assert (toy.backend, plain.backend) == ("toy", "integer")
        decided = [(d.place_id, d.confidence) for d in toy.run_batch(frames)]
        assert decided == [(d.place_id, d.confidence) for d in plain.run_batch(frames)]
        data = load_dataset("synthetic:8", ["winter"], model.config.preprocess)
        query = (data.traversal("winter"), data.place_ids, "winter", SequenceOptions(ks=(1, 3)))
        opened = len(TOY_OPENED)
        simulated = evaluate_fixed_point(model, *query, backend="toy", progress=True)
        assert TOY_OPENED[opened:] == [True]  # opened once, through the registry, with evaluate's progress flag
        assert simulated.rows == evaluate_fixed_point(model, *query).rows
        np.testing.assert_array_equal(simulated.query_counts, evaluate_fixed_point(model, *query).query_counts)
        with pytest.raises(InvalidValueError, match="--backend toy needs a fixed-point model"):
            evaluate_float(load_checkpoint(path), *query, backend="toy")
        capsys.readouterr()
        assert main(["localize", "--help"]) == 0
        assert "toy: a toy" in " ".join(capsys.readouterr().out.split())  # --backend's choices and help
    finally:
        BACKENDS.unregister("toy")


def test_the_walkthrough_registers_what_these_tests_register():
    """Every registry line of docs/architecture.md's walkthrough is one of this file's (but for line breaks)."""
    docs = (Path(__file__).resolve().parents[1] / "docs" / "architecture.md").read_text(encoding="utf-8")
    lines = [line.strip() for line in docs.splitlines() if ".register(" in line and line.strip().endswith("))")]
    assert len(lines) == 4  # a target, a strategy, a channel, a backend
    source = "".join(Path(__file__).read_text(encoding="utf-8").split())
    for line in lines:
        assert "".join(line.split()) in source, line


def test_an_exact_backend_is_checked_by_conformance_through_its_tag(tmp_path, tiny_checkpoint):
    """Issue 42: conformance asks the registry for every exact-integer backend; a new one tagged EXACT is compared
    with the baseline in every cross-implementation check, with no change to verify or export --check."""
    from vprsnn_export.runtime.backends import EXACT, tagged

    assert [k.name for k in tagged(EXACT)] == ["integer", "reference", "onnx"]
    model = quantize_checkpoint(load_checkpoint(tiny_checkpoint), "0" * 64, 4, QuantiseOptions())
    data = load_dataset("synthetic:8", ["winter"], model.config.preprocess)
    spikes = query_spikes(data.traversal("winter"), data.place_ids, "winter", model.config)

    def checks() -> list[str]:
        result = cross_implementation(model, spikes, folder=tmp_path, targets=(), reference_queries=1)
        assert result.passed
        return [c.check for c in result.comparisons]

    before = checks()
    assert before and all(c.startswith("reference stepper:") for c in before)
    BACKENDS.register(BackendKind("toy-exact", FixedPointModel, open_toy, "a toy", tags=frozenset({EXACT})))
    try:
        added = checks()[len(before) :]
    finally:
        BACKENDS.unregister("toy-exact")
    assert added and all(c.startswith("integer simulator:") for c in added)  # the toy wraps the simulator
