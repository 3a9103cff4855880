"""The integer inference of a fixed-point model as an ONNX graph, and a runner on onnxruntime.

Graph inputs and outputs (T and inputs are fixed numbers: onnxruntime refuses another time length or
width, so a (batch, T, inputs) array fed by mistake fails its shape check unless batch = T):

    spikes       [T, batch, inputs]  uint8 (0/1)  time first (denotations DATA_TIME, DATA_BATCH, DATA_FEATURE)
    modules      [2]                 int64   [first, last): run modules first .. last - 1 alone, one WTA over
                                             them (a search window); default [0, M], the whole network
    counts       [batch, run]        int64   output spike counts of the neurons run, [first n, last n)
    saturations  [batch]             int64   voltage clips to +-(2**23 - 1)
    wprob        [batch, places]     float64 W+Prob distribution P(l | Q), 0 counts outside the run (optional)
    raster       [T, batch, run]     bool    output spikes per step           (optional)

What a user needs without the project is in metadata_props (:func:`metadata_props`): the reference
place ids, the input layout, the encoder contract and the decision rule (:mod:`targets.contract`).

Computation (every operation integer; the contract of :mod:`export.model`), on the neurons run
(q, theta and m sliced to the columns [first n, last n), n neurons per module; every neuron by default):

    A[t, n, j] = MatMulInteger(s[t, n, :], q[:, j])          uint8 x uint8 -> int32, exact
    Scan over t with state (V, counts, saturations), V int64 starting at 0 per presentation:
        V   = Div(V (4096 - dv), 4096)                         int64 Div truncates toward zero
        Vn  = V + A[t] * 2**voltage_shift
        V   = Clip(Vn, -(2**23 - 1), 2**23 - 1);  saturations += #(Vn != V)
        C   = V > theta << voltage_shift
        WTA on:  per module (group of n consecutive neurons, src/vprsnn_export/network/modules.py) or over
                 every neuron run (the ensemble's scope):
                 w = ArgMax(Reshape(Where(C, A[t] m, -1), [batch, groups, group]), axis 2) (first index on ties);
                 S = (j mod n == w of j's module) and C
        WTA off: S = C
        V   = Where(C, 0, V);  counts += S

int64 carries the voltage path: V (4096 - dv) reaches 2**35, beyond int32. The W+Prob
head is eq. 9-13 of the readout on float64 (:mod:`runtime.assignment`) with the model's
own calibration S^R, stored as integer counts in the smallest unsigned type that holds
them; S'' and 1 / colsum(S^R) are derived from it in the graph with the same float64
operations as :func:`readout.assignment.weighted_matrix` (so they are the same numbers).

Weight storage (about ``bits`` bits per synapse; :mod:`targets.packing`):

    8 bits     q as a uint8 initializer [inputs, neurons]
    4 bits     q as a UINT4 initializer (ONNX's sub-byte type), Cast to uint8 in the graph
    2, 3, 5, 6, 7 bits
               a uint8 bitstream (values row-major over [inputs, neurons], least significant
               bit first), unpacked in the graph: bits = BitwiseAnd(BitShift(bytes, 0..7), 1),
               q = MatMulInteger(bits as [count, b], [1, 2, ..., 2**(b-1)])
"""

# The docstring above is every exported graph's doc_string (build_onnx): a change to it changes the
# files written. The runner on onnxruntime is in onnx_session.py. One concept, the graph: one line per
# ONNX node, the initializers a group per line (:class:`Nodes`), in the order that keeps exports byte-identical.

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from vprsnn_export.config import wta_group
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import DECAY_BITS, FixedPointModel, validate
from vprsnn_export.io.fileio import atomic_write_bytes
from vprsnn_export.readout.regions import module_layout, regularised_calibration
from vprsnn_export.targets.contract import as_json, decision_rule, encoder_contract, search_rule
from vprsnn_export.targets.packing import PACKING, pack_bits

IR_VERSION = 10  # onnxruntime 1.31 refuses the IR 14 that onnx 1.23 writes by default
OPSET = 21
DOMAIN = "vprsnn-export"
INPUT = "spikes"
MODULES = "modules"  # the optional input [first, last): the modules run (a search window)
INPUT_DENOTATION = ("DATA_TIME", "DATA_BATCH", "DATA_FEATURE")  # ONNX dimension denotations of [T, batch, inputs]
NATIVE_SUB_BYTE = {4: TensorProto.UINT4}  # widths stored in an ONNX sub-byte type that onnxruntime casts (opset 21)
WPROB_ROUNDING = 1e-12  # largest |P_onnx - P_readout| allowed for the float64 W+Prob head
INT32_MAX = (1 << 31) - 1  # MatMulInteger accumulates in int32: max_j sum_i q_ij must not exceed this
INT64, DOUBLE, BOOL = TensorProto.INT64, TensorProto.DOUBLE, TensorProto.BOOL


class Nodes(NamedTuple):
    """Nodes and initializers of (a part of) a graph, kept in the order they are added (the files' byte order)."""

    nodes: list[onnx.NodeProto]
    inits: list[TensorProto]

    def const(self, name: str, value: np.ndarray | np.floating | int | np.integer | list[int]) -> None:
        """An initializer: an array or a float as it is, an integer an int64 scalar, a list an int64 vector."""
        array = value if isinstance(value, np.ndarray | np.floating) else np.asarray(value, dtype=np.int64)
        self.inits.append(numpy_helper.from_array(np.asarray(array), name=name))

    def op(self, op_type: str, inputs: list[str], output: str, **attributes: Any) -> None:
        self.nodes.append(helper.make_node(op_type, inputs, [output], **attributes))

    def nonzero_or_one(self, value: str, positive: str, safe: str) -> None:
        """``positive`` = value > 0 and ``safe`` = Where(positive, value, 1): a divisor that is never 0."""
        self.op("Greater", [value, "f_zero"], positive)
        self.op("Where", [positive, value, "f_one"], safe)

    def extend(self, part: Nodes) -> Nodes:
        self.nodes.extend(part.nodes)
        self.inits.extend(part.inits)
        return self


def zeros(dtype: type) -> TensorProto:
    """The one-element zero a ConstantOfShape node fills with."""
    return numpy_helper.from_array(np.zeros(1, dtype=dtype))


def check_exportable(model: FixedPointModel) -> None:
    """The graph implements state isolation (V = 0 at t = 0 of every presentation); :func:`validate` bounds the
    mantissas to 8 bits, MatMulInteger's operands."""
    validate(model, Path("<fixed-point model>"))
    if not model.config.network.state_isolation:
        raise InvalidValueError(
            "the ONNX graph zeroes the voltage at the start of every presentation; "
            "this model was built with state isolation off, which the ONNX target does not express"
        )
    bound = int(model.weight_mantissa.astype(np.int64).sum(axis=0).max()) if model.weight_mantissa.size else 0
    if bound > INT32_MAX:
        raise InvalidValueError(
            f"a current sum reaches {bound} (max_j sum_i q_ij), beyond MatMulInteger's int32 accumulator "
            f"({INT32_MAX}): the graph would wrap (about 8.4 M inputs at 8 bits); use fewer inputs or another target"
        )


def window_nodes(model: FixedPointModel) -> Nodes:
    """The neurons run, from the ``modules`` input [first, last): ``window_start`` = first n and ``window_stop`` =
    last n ([1] each, n neurons per module) and ``window_size`` = their difference (a scalar)."""
    g = Nodes([], [])
    g.const("module_neurons", [model.config.network.n_neurons])
    g.const("at_zero", [0])
    g.const("at_one", [1])
    g.const("at_two", [2])
    g.op("Slice", [MODULES, "at_zero", "at_one"], "first_module")
    g.op("Slice", [MODULES, "at_one", "at_two"], "last_module")
    g.op("Mul", ["first_module", "module_neurons"], "window_start")
    g.op("Mul", ["last_module", "module_neurons"], "window_stop")
    g.op("Sub", ["window_stop", "window_start"], "window_span")
    g.op("ReduceSum", ["window_span", "at_zero"], "window_size", keepdims=0)
    return g


def neuron_nodes(model: FixedPointModel) -> Nodes:
    """The per-neuron int64 vectors the step reads from the outer graph, stored narrow, widened and sliced to the
    neurons run once.

    vth = theta << voltage_shift;  with WTA also multiplier = m and neuron_index = 0 .. group - 1 (Range),
    the index of a neuron within its WTA group (config.wta_group: one module's n neurons, or every neuron run)
    """
    g = Nodes([], [])
    g.const("threshold_stored", smallest_unsigned(model.threshold))
    g.const("vth_scale", 1 << model.voltage_shift)
    g.op("Cast", ["threshold_stored"], "threshold_wide", to=INT64)
    g.op("Mul", ["threshold_wide", "vth_scale"], "vth_all")
    g.op("Slice", ["vth_all", "window_start", "window_stop", "at_zero"], "vth")
    if model.config.network.wta:
        group = wta_group(model.config, model.n_neurons)
        g.const("multiplier_stored", smallest_unsigned(model.scale_multiplier))
        g.const("index_start", 0)
        g.const("index_step", 1)
        g.op("Cast", ["multiplier_stored"], "multiplier_all", to=INT64)
        g.op("Slice", ["multiplier_all", "window_start", "window_stop", "at_zero"], "multiplier")
        limit = "window_size"
        if group < model.n_neurons:  # one module's neurons: the same group whatever the window
            g.const("index_limit", group)
            limit = "index_limit"
        g.op("Range", ["index_start", limit, "index_step"], "neuron_index")
    return g


def step_body(model: FixedPointModel, with_raster: bool) -> onnx.GraphProto:
    """One time step: (V, counts, saturations, A[t]) -> (V', counts', saturations' [, S]).

    ``vth``, ``multiplier`` and ``neuron_index`` come from the outer graph (:func:`neuron_nodes`).
    """
    n = model.n_neurons
    run = "neurons_run"  # the symbolic width of the neurons run
    g = Nodes([], [])
    g.const("keep", (1 << DECAY_BITS) - model.decay_dv)
    g.const("unity", 1 << DECAY_BITS)
    g.const("shift", 1 << model.voltage_shift)
    g.const("vmin", -model.voltage_limit)
    g.const("vmax", model.voltage_limit)
    g.const("zero", 0)
    g.const("axis1", [1])
    g.op("Cast", ["a_t"], "a", to=INT64)
    g.op("Mul", ["v_in", "keep"], "v_keep")
    g.op("Div", ["v_keep", "unity"], "v_decayed")
    g.op("Mul", ["a", "shift"], "a_shifted")
    g.op("Add", ["v_decayed", "a_shifted"], "v_raw")
    g.op("Clip", ["v_raw", "vmin", "vmax"], "v_clip")
    g.op("Equal", ["v_raw", "v_clip"], "unclipped")
    g.op("Not", ["unclipped"], "clipped")
    g.op("Cast", ["clipped"], "clipped_i", to=INT64)
    g.op("ReduceSum", ["clipped_i", "axis1"], "clips", keepdims=0)
    g.op("Add", ["sat_in", "clips"], "sat_out")
    g.op("Greater", ["v_clip", "vth"], "cand")
    g.op("Where", ["cand", "zero", "v_clip"], "v_out")
    if model.config.network.wta:
        group = wta_group(model.config, n)
        g.const("minus_one", -1)
        g.const("group_shape", [0, -1, group] if group < n else [0, 1, -1])  # (batch, groups, group)
        g.const("flat_state", [0, -1])
        g.op("Mul", ["a", "multiplier"], "score")
        g.op("Where", ["cand", "score", "minus_one"], "masked")
        g.op("Reshape", ["masked", "group_shape"], "grouped")
        g.op("ArgMax", ["grouped"], "winner", axis=2, keepdims=1, select_last_index=0)
        g.op("Equal", ["neuron_index", "winner"], "is_winner_grouped")
        g.op("Reshape", ["is_winner_grouped", "flat_state"], "is_winner")
        g.op("And", ["is_winner", "cand"], "fired")
    else:
        g.op("Identity", ["cand"], "fired")
    g.op("Cast", ["fired"], "fired_i", to=INT64)
    g.op("Add", ["counts_in", "fired_i"], "counts_out")
    state: dict[str, list[str | int]] = {"v": ["batch", run], "counts": ["batch", run], "sat": ["batch"]}  # int64
    outputs = [helper.make_tensor_value_info(f"{name}_out", INT64, shape) for name, shape in state.items()]
    if with_raster:
        g.op("Identity", ["fired"], "fired_out")
        outputs.append(helper.make_tensor_value_info("fired_out", BOOL, ["batch", run]))
    inputs = [helper.make_tensor_value_info(f"{name}_in", INT64, shape) for name, shape in state.items()]
    inputs.append(helper.make_tensor_value_info("a_t", TensorProto.INT32, ["batch", run]))
    return helper.make_graph(g.nodes, "lif_wta_step", inputs, outputs, g.inits)


def weight_storage(bits: int) -> str:
    """How the graph stores ``bits``-bit mantissas (the ``vprsnn.weight_storage`` property)."""
    if bits == 8:
        return "uint8"
    if bits in NATIVE_SUB_BYTE:
        return f"{TensorProto.DataType.Name(NATIVE_SUB_BYTE[bits]).lower()} initializer, Cast to uint8"
    return f"{PACKING} of {bits}-bit values over [inputs, neurons], unpacked in the graph"


def weight_nodes(model: FixedPointModel) -> Nodes:
    """Nodes yielding ``weight_mantissa`` uint8 [inputs, neurons] from the stored initializer (module docstring)."""
    q, bits = model.weight_mantissa, model.bits
    g = Nodes([], [])
    if bits == 8:
        g.const("weight_mantissa", q.astype(np.uint8))
        return g
    packed = pack_bits(q, bits)
    if bits in NATIVE_SUB_BYTE:
        g.inits.append(
            helper.make_tensor("weight_packed", NATIVE_SUB_BYTE[bits], list(q.shape), packed.tobytes(), raw=True)
        )
        g.op("Cast", ["weight_packed"], "weight_mantissa", to=TensorProto.UINT8)
        return g
    g.const("weight_packed", packed[:, None])
    g.const("bit_positions", np.arange(8, dtype=np.uint8)[None, :])
    g.const("bit_one", np.array(1, dtype=np.uint8))
    g.const("stream_flat", [-1])
    g.const("stream_start", [0])
    g.const("stream_end", [q.size * bits])
    g.const("digit_shape", [q.size, bits])
    g.const("place_values", (1 << np.arange(bits, dtype=np.uint8))[:, None].astype(np.uint8))
    g.const("weight_shape", list(q.shape))
    g.op("BitShift", ["weight_packed", "bit_positions"], "bit_shifted", direction="RIGHT")
    g.op("BitwiseAnd", ["bit_shifted", "bit_one"], "bit_plane")
    g.op("Reshape", ["bit_plane", "stream_flat"], "bit_stream")
    g.op("Slice", ["bit_stream", "stream_start", "stream_end"], "value_bits")
    g.op("Reshape", ["value_bits", "digit_shape"], "digits")
    g.op("MatMulInteger", ["digits", "place_values"], "values_i32")
    g.op("Cast", ["values_i32"], "values_u8", to=TensorProto.UINT8)
    g.op("Reshape", ["values_u8", "weight_shape"], "weight_mantissa")
    return g


def currents_nodes(model: FixedPointModel) -> Nodes:
    """A[T, batch, run] int32 = MatMulInteger(spikes reshaped [T batch, inputs], q of the neurons run); initial
    state zeros."""
    g = weight_nodes(model)
    g.const("flat_shape", [-1, model.n_inputs])
    g.op("Slice", ["weight_mantissa", "window_start", "window_stop", "at_one"], "window_weights")
    g.op("Shape", ["window_weights"], "window_shape")
    g.op("Slice", ["window_shape", "at_one", "at_two"], "neurons")
    g.op("Shape", [INPUT], "spike_shape")
    g.op("Slice", ["spike_shape", "at_zero", "at_two"], "time_batch")
    g.op("Slice", ["spike_shape", "at_one", "at_two"], "batch")
    g.op("Reshape", [INPUT, "flat_shape"], "flat_spikes")
    g.op("MatMulInteger", ["flat_spikes", "window_weights"], "flat_currents")
    g.op("Concat", ["time_batch", "neurons"], "current_shape", axis=0)
    g.op("Reshape", ["flat_currents", "current_shape"], "currents")
    g.op("Concat", ["batch", "neurons"], "state_shape", axis=0)
    g.op("ConstantOfShape", ["state_shape"], "v0", value=zeros(np.int64))
    g.op("ConstantOfShape", ["batch"], "sat0", value=zeros(np.int64))
    return g


def smallest_unsigned(values: np.ndarray) -> np.ndarray:
    """``values`` (non-negative integers) in the narrowest unsigned dtype that holds them exactly."""
    return values.astype(np.min_scalar_type(int(values.max()) if values.size else 0))


def calibration_nodes(counts: np.ndarray) -> Nodes:
    """``s_r`` float64 [neurons, places] from S^R stored in the fewer bytes of two exact forms.

    dense:  the counts in the narrowest unsigned type, Cast to float64
    sparse: the non-zero counts and their row-major positions, each in the narrowest unsigned
            type, ScatterND into zeros (S^R of a WTA network is mostly zeros: each place's T
            spikes go to a few neurons)
    """
    g = Nodes([], [])
    dense = smallest_unsigned(counts)
    flat = counts.reshape(-1)
    where = np.flatnonzero(flat)
    values, positions = smallest_unsigned(flat[where]), smallest_unsigned(where)
    if dense.nbytes <= values.nbytes + positions.nbytes:
        g.const("s_r_counts", dense)
        g.op("Cast", ["s_r_counts"], "s_r", to=DOUBLE)
        return g
    g.const("s_r_values", values)
    g.const("s_r_positions", positions[:, None])
    g.const("s_r_size", [flat.size])
    g.const("s_r_shape", list(counts.shape))
    g.op("ConstantOfShape", ["s_r_size"], "s_r_zeros", value=zeros(np.float64))
    g.op("Cast", ["s_r_values"], "s_r_nonzero", to=DOUBLE)
    g.op("Cast", ["s_r_positions"], "s_r_index", to=INT64)
    g.op("ScatterND", ["s_r_zeros", "s_r_index", "s_r_nonzero"], "s_r_flat")
    g.op("Reshape", ["s_r_flat", "s_r_shape"], "s_r")
    return g


def readout_calibration(model: FixedPointModel) -> tuple[np.ndarray, np.ndarray | None]:
    """The S^R the readout uses and the neurons it keeps: for an ensemble the region regularisation of
    :mod:`vprsnn_export.readout.regions` (S~ = S^R scaled by lambda outside each neuron's region, the
    hyperactive neurons' rows zeroed; keep = not silent), else (S^R, None). Decided from S^R alone."""
    if model.config.train.module_size <= 0:
        return model.calibration, None
    weighted, silent = regularised_calibration(
        model.calibration, module_layout(model.config, model.calibration.shape[1])
    )
    return weighted, ~silent


def readout_matrix_nodes(model: FixedPointModel, matrix: np.ndarray) -> Nodes:
    """``s_r``, ``s_double_prime`` and ``inv_colsum`` (float64) from the integer counts S^R (eq. 9-10).

    omega_i = #{l : S^R_il > 0};  S'_il = S^R_il / omega_i where omega_i > gamma places, else S^R_il
    S''_il  = S'_il (S^R_il / sum_m S^R_im)  (a silent row is 0);  inv_colsum_l = 1 / sum_i S^R_il, 0 where 0
    Each is one correctly rounded float64 operation on exact integers, as in weighted_matrix.
    ``matrix``: the S^R the readout uses (:func:`readout_calibration`).
    """
    if np.array_equal(matrix, np.round(matrix)):  # counts (a single network, lambda 0 or 1): stored exactly as integers
        g = calibration_nodes(np.round(matrix).astype(np.int64))
    else:
        g = Nodes([], [])
        g.const("s_r_weighted", matrix)
        g.op("Identity", ["s_r_weighted"], "s_r")
    g.const("involvement", np.float64(float(model.config.assignment.gamma) * model.calibration.shape[1]))
    g.const("axis0_outer", [0])
    g.const("f_zero", np.float64(0.0))
    g.const("f_one", np.float64(1.0))
    g.const("axis1_outer", [1])
    g.op("Greater", ["s_r", "f_zero"], "s_r_positive")
    g.op("Cast", ["s_r_positive"], "s_r_involved", to=DOUBLE)
    g.op("ReduceSum", ["s_r_involved", "axis1_outer"], "omega", keepdims=1)
    g.op("Greater", ["omega", "involvement"], "penalised")
    g.op("Where", ["penalised", "omega", "f_one"], "divisor")
    g.op("Div", ["s_r", "divisor"], "s_prime")
    g.op("ReduceSum", ["s_r", "axis1_outer"], "rowsum", keepdims=1)
    g.nonzero_or_one("rowsum", "row_active", "row_safe")
    g.op("Div", ["s_r", "row_safe"], "row_share")
    g.op("Mul", ["s_prime", "row_share"], "s_double_prime")
    g.op("ReduceSum", ["s_r", "axis0_outer"], "colsum", keepdims=1)
    g.nonzero_or_one("colsum", "col_active", "col_safe")
    g.op("Div", ["f_one", "col_safe"], "col_inverse")
    g.op("Where", ["col_active", "col_inverse", "f_zero"], "inv_colsum")
    return g


def wprob_nodes(model: FixedPointModel) -> Nodes:
    """P(l | Q) from counts: eq. 9-11 scores, min-max normalised, L1 normalised (eq. 12-13).

    An ensemble's head reads out with its region regularisation (:func:`readout_calibration`), on the counts of
    every neuron (Pad: 0 outside the neurons run).

    scores = (S^Q S'') * (([S^Q > 0] S^R) / colsum(S^R)),  0 where colsum = 0
    P      = (scores - min) / (max - min) / sum(...),     uniform where max == min
    """
    matrix, keep = readout_calibration(model)
    g = readout_matrix_nodes(model, matrix)
    g.const("uniform", np.float64(1.0 / model.calibration.shape[1]))
    g.const("i_zero", 0)
    g.const("route_neurons", [model.n_neurons])
    g.op("Sub", ["route_neurons", "window_stop"], "neurons_after")
    g.op("Concat", ["at_zero", "window_start", "at_zero", "neurons_after"], "counts_pads", axis=0)
    g.op("Pad", ["counts", "counts_pads"], "route_counts")
    counts = "route_counts"
    if keep is not None:  # an ensemble: the silenced neurons' counts do not reach the readout
        g.const("readout_keep", keep.astype(np.int64))
        g.op("Mul", ["route_counts", "readout_keep"], "readout_counts")
        counts = "readout_counts"
    g.op("Cast", [counts], "sq", to=DOUBLE)
    g.op("MatMul", ["sq", "s_double_prime"], "raw")
    g.op("Greater", [counts, "i_zero"], "active_b")
    g.op("Cast", ["active_b"], "active", to=DOUBLE)
    g.op("MatMul", ["active", "s_r"], "covered")
    g.op("Mul", ["covered", "inv_colsum"], "penalty")
    g.op("Mul", ["raw", "penalty"], "scores")
    g.op("ReduceMin", ["scores", "axis1_outer"], "lo", keepdims=1)
    g.op("ReduceMax", ["scores", "axis1_outer"], "hi", keepdims=1)
    g.op("Sub", ["hi", "lo"], "span")
    g.nonzero_or_one("span", "spread", "span_safe")
    g.op("Sub", ["scores", "lo"], "shifted")
    g.op("Div", ["shifted", "span_safe"], "norm")
    g.op("ReduceSum", ["norm", "axis1_outer"], "total", keepdims=1)
    g.nonzero_or_one("total", "positive", "total_safe")
    g.op("Div", ["norm", "total_safe"], "dist")
    g.op("Where", ["spread", "dist", "uniform"], "wprob")
    return g


def build_onnx(model: FixedPointModel, *, with_wprob: bool = True, with_raster: bool = False) -> onnx.ModelProto:
    """The ONNX model of ``model``'s integer inference (see the module docstring)."""
    check_exportable(model)
    timesteps, run = model.config.encoder.timesteps, "neurons_run"
    g = window_nodes(model).extend(currents_nodes(model)).extend(neuron_nodes(model))
    g.const(MODULES, [0, model.n_neurons // model.config.network.n_neurons])  # the input's default
    scan_outputs = ["v_final", "counts", "saturations"] + (["raster"] if with_raster else [])
    scan = helper.make_node(
        "Scan", ["v0", "v0", "sat0", "currents"], scan_outputs, body=step_body(model, with_raster), num_scan_inputs=1
    )
    g.nodes.append(scan)
    outputs = [
        helper.make_tensor_value_info("counts", INT64, ["batch", run]),
        helper.make_tensor_value_info("saturations", INT64, ["batch"]),
    ]
    if with_wprob:
        g.extend(wprob_nodes(model))
        outputs.append(helper.make_tensor_value_info("wprob", DOUBLE, ["batch", model.calibration.shape[1]]))
    if with_raster:
        outputs.append(helper.make_tensor_value_info("raster", BOOL, [timesteps, "batch", run]))
    spikes = helper.make_tensor_value_info(
        INPUT,
        TensorProto.UINT8,
        [timesteps, "batch", model.n_inputs],
        doc_string=input_layout(model),
        shape_denotation=list(INPUT_DENOTATION),
    )
    modules = helper.make_tensor_value_info(MODULES, INT64, [2], doc_string=MODULES_LAYOUT)
    graph = helper.make_graph(g.nodes, "vprsnn_integer_inference", [spikes, modules], outputs, g.inits)
    onnx_model = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", OPSET)],
        ir_version=IR_VERSION,
        producer_name="vprsnn-export",
        doc_string=__doc__,
    )
    onnx_model.domain = DOMAIN
    helper.set_model_props(onnx_model, metadata_props(model, with_wprob=with_wprob))
    onnx.checker.check_model(onnx_model, full_check=True)
    return onnx_model


MODULES_LAYOUT = (
    "modules [2] int64 [first, last), default [0, M]: run modules first .. last - 1 alone (a search window; "
    "vprsnn.search), counts and raster then of neurons [first n, last n)"
)


def input_layout(model: FixedPointModel) -> str:
    """The ``spikes`` input's layout in words (its doc_string and the ``vprsnn.input_layout`` property)."""
    timesteps = model.config.encoder.timesteps
    return (
        f"spikes [T = {timesteps}, batch, inputs = {model.n_inputs}] uint8 0/1, time first: presentations held as "
        f"(batch, T, inputs) are fed as x.transpose(1, 0, 2); onnxruntime refuses another T or width"
    )


def metadata_props(model: FixedPointModel, *, with_wprob: bool = True) -> dict[str, str]:
    """Key facts as ONNX metadata_props (strings), with what a user needs to decide without the project (JSON)."""
    cfg = model.config
    props = {
        "vprsnn.format": "vprsnn-onnx/1",
        "vprsnn.bits": str(model.bits),
        "vprsnn.decay_dv": str(model.decay_dv),
        "vprsnn.voltage_shift": str(model.voltage_shift),
        "vprsnn.voltage_bits": str(model.voltage_bits),
        "vprsnn.scale_exponent": str(model.scale_exponent),
        "vprsnn.wta": "on" if cfg.network.wta else "off",
        "vprsnn.wta_group": str(wta_group(cfg, model.n_neurons)),
        "vprsnn.modules": str(model.n_neurons // cfg.network.n_neurons),
        "vprsnn.timesteps": str(cfg.encoder.timesteps),
        "vprsnn.encoder": f"Bernoulli(clip({cfg.encoder.rate_scale} * pixel, 0, 1)), seed {cfg.seed}",
        "vprsnn.source_sha256": model.source_sha256,
        "vprsnn.gamma": repr(cfg.assignment.gamma),
        "vprsnn.weight_storage": weight_storage(model.bits),
        "vprsnn.reference_place_ids": as_json(model.reference_place_ids.astype(int).tolist()),
        "vprsnn.input_layout": input_layout(model),
        "vprsnn.encoder_contract": as_json(encoder_contract(cfg)),
    }
    if with_wprob:
        props["vprsnn.decision"] = as_json(decision_rule("wprob"))
    if cfg.train.module_size > 0:
        props["vprsnn.search"] = as_json(search_rule(cfg.train.module_size, len(model.reference_place_ids)))
    return props


def write_onnx(model: FixedPointModel, path: str | Path, *, with_wprob: bool = True, with_raster: bool = False) -> Path:
    """Build, check and write the graph atomically."""
    data = build_onnx(model, with_wprob=with_wprob, with_raster=with_raster).SerializeToString()
    return atomic_write_bytes(path, data)
