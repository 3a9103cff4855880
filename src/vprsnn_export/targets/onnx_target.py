"""The integer inference of a fixed-point model as an ONNX graph, and a runner on onnxruntime.

Graph inputs and outputs (T and inputs are fixed numbers: onnxruntime refuses another time length or
width, so a (batch, T, inputs) array fed by mistake fails its shape check unless batch = T):

    spikes       [T, batch, inputs]  uint8 (0/1)  time first (denotations DATA_TIME, DATA_BATCH, DATA_FEATURE)
    counts       [batch, neurons]    int64   output spike counts
    saturations  [batch]             int64   voltage clips to +-(2**23 - 1)
    wprob        [batch, places]     float64 W+Prob distribution P(l | Q)   (optional)
    raster       [T, batch, neurons] bool    output spikes per step           (optional)

What a user needs without the project is in metadata_props (:func:`metadata_props`): the reference
place ids, the input layout, the encoder contract and the decision rule (:mod:`targets.contract`).

Computation (every operation integer; the contract of :mod:`export.model`):

    A[t, n, j] = MatMulInteger(s[t, n, :], q[:, j])          uint8 x uint8 -> int32, exact
    Scan over t with state (V, counts, saturations), V int64 starting at 0 per presentation:
        V   = Div(V (4096 - dv), 4096)                         int64 Div truncates toward zero
        Vn  = V + A[t] * 2**voltage_shift
        V   = Clip(Vn, -(2**23 - 1), 2**23 - 1);  saturations += #(Vn != V)
        C   = V > theta << voltage_shift
        WTA on:  per module (group of n consecutive neurons, src/vprsnn_export/network/modules.py):
                 w = ArgMax(Reshape(Where(C, A[t] m, -1), [batch, M, n]), axis 2) (first index on ties);
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
# files written. The runner on onnxruntime is in onnx_session.py. Over 400 lines because it is one
# concept, the graph: one line per ONNX node and initializer, in the order that keeps exports byte-identical.

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from vprsnn_export.config import wta_group
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.export.model import DECAY_BITS, FixedPointModel, validate
from vprsnn_export.io.fileio import atomic_write_bytes
from vprsnn_export.readout.regions import module_layout, regularised_calibration
from vprsnn_export.targets.contract import as_json, decision_rule, encoder_contract
from vprsnn_export.targets.packing import PACKING, pack_bits

IR_VERSION = 10  # onnxruntime 1.31 refuses the IR 14 that onnx 1.23 writes by default
OPSET = 21
DOMAIN = "vprsnn-export"
INPUT = "spikes"
INPUT_DENOTATION = ("DATA_TIME", "DATA_BATCH", "DATA_FEATURE")  # ONNX dimension denotations of [T, batch, inputs]
NATIVE_SUB_BYTE = {4: TensorProto.UINT4}  # widths stored in an ONNX sub-byte type that onnxruntime casts (opset 21)


WPROB_ROUNDING = 1e-12  # largest |P_onnx - P_readout| allowed for the float64 W+Prob head


def const(name: str, value: np.ndarray | np.generic) -> TensorProto:
    return numpy_helper.from_array(np.asarray(value), name=name)


INT32_MAX = (1 << 31) - 1  # MatMulInteger accumulates in int32: max_j sum_i q_ij must not exceed this


def check_exportable(model: FixedPointModel) -> None:
    """The graph implements state isolation (V = 0 at t = 0 of every presentation) and 8-bit-or-less mantissas."""
    validate(model, Path("<fixed-point model>"))
    if not model.config.network.state_isolation:
        raise InvalidValueError(
            "the ONNX graph zeroes the voltage at the start of every presentation; "
            "this model was built with state isolation off, which the ONNX target does not express"
        )
    if model.bits > 8:
        raise InvalidValueError(f"MatMulInteger takes 8-bit operands; {model.bits}-bit mantissas do not fit")
    bound = int(model.weight_mantissa.astype(np.int64).sum(axis=0).max()) if model.weight_mantissa.size else 0
    if bound > INT32_MAX:
        raise InvalidValueError(
            f"a current sum reaches {bound} (max_j sum_i q_ij), beyond MatMulInteger's int32 accumulator "
            f"({INT32_MAX}): the graph would wrap (about 8.4 M inputs at 8 bits); use fewer inputs or another target"
        )


def neuron_nodes(model: FixedPointModel) -> tuple[list[onnx.NodeProto], list[TensorProto]]:
    """The per-neuron int64 vectors the step reads from the outer graph, stored narrow and widened once.

    vth = theta << voltage_shift;  with WTA also multiplier = m and neuron_index = 0 .. n - 1 (Range),
    the index of a neuron within its WTA group (config.wta_group: the ensemble, or one module's n neurons)
    """
    inits = [
        const("threshold_stored", smallest_unsigned(model.threshold)),
        const("vth_scale", np.int64(1 << model.voltage_shift)),
    ]
    nodes = [
        helper.make_node("Cast", ["threshold_stored"], ["threshold_wide"], to=TensorProto.INT64),
        helper.make_node("Mul", ["threshold_wide", "vth_scale"], ["vth"]),
    ]
    if model.config.network.wta:
        inits += [
            const("multiplier_stored", smallest_unsigned(model.scale_multiplier)),
            const("index_start", np.int64(0)),
            const("index_limit", np.int64(wta_group(model.config, model.n_neurons))),
            const("index_step", np.int64(1)),
        ]
        nodes += [
            helper.make_node("Cast", ["multiplier_stored"], ["multiplier"], to=TensorProto.INT64),
            helper.make_node("Range", ["index_start", "index_limit", "index_step"], ["neuron_index"]),
        ]
    return nodes, inits


def step_body(model: FixedPointModel, with_raster: bool) -> onnx.GraphProto:
    """One time step: (V, counts, saturations, A[t]) -> (V', counts', saturations' [, S]).

    ``vth``, ``multiplier`` and ``neuron_index`` come from the outer graph (:func:`neuron_nodes`).
    """
    n = model.n_neurons
    shift = 1 << model.voltage_shift
    limit = model.voltage_limit
    keep = (1 << DECAY_BITS) - model.decay_dv
    inits = [
        const("keep", np.int64(keep)),
        const("unity", np.int64(1 << DECAY_BITS)),
        const("shift", np.int64(shift)),
        const("vmin", np.int64(-limit)),
        const("vmax", np.int64(limit)),
        const("zero", np.int64(0)),
        const("axis1", np.array([1], dtype=np.int64)),
    ]
    nodes = [
        helper.make_node("Cast", ["a_t"], ["a"], to=TensorProto.INT64),
        helper.make_node("Mul", ["v_in", "keep"], ["v_keep"]),
        helper.make_node("Div", ["v_keep", "unity"], ["v_decayed"]),
        helper.make_node("Mul", ["a", "shift"], ["a_shifted"]),
        helper.make_node("Add", ["v_decayed", "a_shifted"], ["v_raw"]),
        helper.make_node("Clip", ["v_raw", "vmin", "vmax"], ["v_clip"]),
        helper.make_node("Equal", ["v_raw", "v_clip"], ["unclipped"]),
        helper.make_node("Not", ["unclipped"], ["clipped"]),
        helper.make_node("Cast", ["clipped"], ["clipped_i"], to=TensorProto.INT64),
        helper.make_node("ReduceSum", ["clipped_i", "axis1"], ["clips"], keepdims=0),
        helper.make_node("Add", ["sat_in", "clips"], ["sat_out"]),
        helper.make_node("Greater", ["v_clip", "vth"], ["cand"]),
        helper.make_node("Where", ["cand", "zero", "v_clip"], ["v_out"]),
    ]
    if model.config.network.wta:
        group = wta_group(model.config, n)
        inits += [
            const("minus_one", np.int64(-1)),
            const("group_shape", np.array([0, n // group, group], dtype=np.int64)),  # (batch, M, n)
            const("flat_state", np.array([0, n], dtype=np.int64)),
        ]
        nodes += [
            helper.make_node("Mul", ["a", "multiplier"], ["score"]),
            helper.make_node("Where", ["cand", "score", "minus_one"], ["masked"]),
            helper.make_node("Reshape", ["masked", "group_shape"], ["grouped"]),
            helper.make_node("ArgMax", ["grouped"], ["winner"], axis=2, keepdims=1, select_last_index=0),
            helper.make_node("Equal", ["neuron_index", "winner"], ["is_winner_grouped"]),
            helper.make_node("Reshape", ["is_winner_grouped", "flat_state"], ["is_winner"]),
            helper.make_node("And", ["is_winner", "cand"], ["fired"]),
        ]
    else:
        nodes.append(helper.make_node("Identity", ["cand"], ["fired"]))
    nodes += [
        helper.make_node("Cast", ["fired"], ["fired_i"], to=TensorProto.INT64),
        helper.make_node("Add", ["counts_in", "fired_i"], ["counts_out"]),
    ]
    outputs = [
        helper.make_tensor_value_info("v_out", TensorProto.INT64, ["batch", n]),
        helper.make_tensor_value_info("counts_out", TensorProto.INT64, ["batch", n]),
        helper.make_tensor_value_info("sat_out", TensorProto.INT64, ["batch"]),
    ]
    if with_raster:
        nodes.append(helper.make_node("Identity", ["fired"], ["fired_out"]))
        outputs.append(helper.make_tensor_value_info("fired_out", TensorProto.BOOL, ["batch", n]))
    inputs = [
        helper.make_tensor_value_info("v_in", TensorProto.INT64, ["batch", n]),
        helper.make_tensor_value_info("counts_in", TensorProto.INT64, ["batch", n]),
        helper.make_tensor_value_info("sat_in", TensorProto.INT64, ["batch"]),
        helper.make_tensor_value_info("a_t", TensorProto.INT32, ["batch", n]),
    ]
    return helper.make_graph(nodes, "lif_wta_step", inputs, outputs, inits)


def weight_storage(bits: int) -> str:
    """How the graph stores ``bits``-bit mantissas (the ``vprsnn.weight_storage`` property)."""
    if bits == 8:
        return "uint8"
    if bits in NATIVE_SUB_BYTE:
        return f"{TensorProto.DataType.Name(NATIVE_SUB_BYTE[bits]).lower()} initializer, Cast to uint8"
    return f"{PACKING} of {bits}-bit values over [inputs, neurons], unpacked in the graph"


def weight_nodes(model: FixedPointModel) -> tuple[list[onnx.NodeProto], list[TensorProto]]:
    """Nodes yielding ``weight_mantissa`` uint8 [inputs, neurons] from the stored initializer (module docstring)."""
    q, bits = model.weight_mantissa, model.bits
    if bits == 8:
        return [], [const("weight_mantissa", q.astype(np.uint8))]
    packed = pack_bits(q, bits)
    if bits in NATIVE_SUB_BYTE:
        stored = helper.make_tensor("weight_packed", NATIVE_SUB_BYTE[bits], list(q.shape), packed.tobytes(), raw=True)
        return [helper.make_node("Cast", ["weight_packed"], ["weight_mantissa"], to=TensorProto.UINT8)], [stored]
    count = q.size
    inits = [
        const("weight_packed", packed[:, None]),
        const("bit_positions", np.arange(8, dtype=np.uint8)[None, :]),
        const("bit_one", np.uint8(1)),
        const("stream_flat", np.array([-1], dtype=np.int64)),
        const("stream_start", np.array([0], dtype=np.int64)),
        const("stream_end", np.array([count * bits], dtype=np.int64)),
        const("digit_shape", np.array([count, bits], dtype=np.int64)),
        const("place_values", (1 << np.arange(bits, dtype=np.uint8))[:, None].astype(np.uint8)),
        const("weight_shape", np.array(q.shape, dtype=np.int64)),
    ]
    nodes = [
        helper.make_node("BitShift", ["weight_packed", "bit_positions"], ["bit_shifted"], direction="RIGHT"),
        helper.make_node("BitwiseAnd", ["bit_shifted", "bit_one"], ["bit_plane"]),
        helper.make_node("Reshape", ["bit_plane", "stream_flat"], ["bit_stream"]),
        helper.make_node("Slice", ["bit_stream", "stream_start", "stream_end"], ["value_bits"]),
        helper.make_node("Reshape", ["value_bits", "digit_shape"], ["digits"]),
        helper.make_node("MatMulInteger", ["digits", "place_values"], ["values_i32"]),
        helper.make_node("Cast", ["values_i32"], ["values_u8"], to=TensorProto.UINT8),
        helper.make_node("Reshape", ["values_u8", "weight_shape"], ["weight_mantissa"]),
    ]
    return nodes, inits


def currents_nodes(model: FixedPointModel) -> tuple[list[onnx.NodeProto], list[TensorProto]]:
    """A[T, batch, neurons] int32 = MatMulInteger(spikes reshaped [T batch, inputs], q); initial state zeros."""
    unpack, inits = weight_nodes(model)
    inits += [
        const("flat_shape", np.array([-1, model.n_inputs], dtype=np.int64)),
        const("neurons", np.array([model.n_neurons], dtype=np.int64)),
        const("first_two", np.array([0], dtype=np.int64)),
        const("two", np.array([2], dtype=np.int64)),
        const("one", np.array([1], dtype=np.int64)),
    ]
    nodes = unpack + [
        helper.make_node("Shape", [INPUT], ["spike_shape"]),
        helper.make_node("Slice", ["spike_shape", "first_two", "two"], ["time_batch"]),
        helper.make_node("Slice", ["spike_shape", "one", "two"], ["batch"]),
        helper.make_node("Reshape", [INPUT, "flat_shape"], ["flat_spikes"]),
        helper.make_node("MatMulInteger", ["flat_spikes", "weight_mantissa"], ["flat_currents"]),
        helper.make_node("Concat", ["time_batch", "neurons"], ["current_shape"], axis=0),
        helper.make_node("Reshape", ["flat_currents", "current_shape"], ["currents"]),
        helper.make_node("Concat", ["batch", "neurons"], ["state_shape"], axis=0),
        helper.make_node(
            "ConstantOfShape", ["state_shape"], ["v0"], value=numpy_helper.from_array(np.zeros(1, dtype=np.int64))
        ),
        helper.make_node(
            "ConstantOfShape", ["batch"], ["sat0"], value=numpy_helper.from_array(np.zeros(1, dtype=np.int64))
        ),
    ]
    return nodes, inits


def smallest_unsigned(values: np.ndarray) -> np.ndarray:
    """``values`` (non-negative integers) in the narrowest unsigned dtype that holds them exactly."""
    return values.astype(np.min_scalar_type(int(values.max()) if values.size else 0))


def calibration_nodes(counts: np.ndarray) -> tuple[list[onnx.NodeProto], list[TensorProto]]:
    """``s_r`` float64 [neurons, places] from S^R stored in the fewer bytes of two exact forms.

    dense:  the counts in the narrowest unsigned type, Cast to float64
    sparse: the non-zero counts and their row-major positions, each in the narrowest unsigned
            type, ScatterND into zeros (S^R of a WTA network is mostly zeros: each place's T
            spikes go to a few neurons)
    """
    dense = smallest_unsigned(counts)
    flat = counts.reshape(-1)
    where = np.flatnonzero(flat)
    values, positions = smallest_unsigned(flat[where]), smallest_unsigned(where)
    if dense.nbytes <= values.nbytes + positions.nbytes:
        return [helper.make_node("Cast", ["s_r_counts"], ["s_r"], to=TensorProto.DOUBLE)], [const("s_r_counts", dense)]
    inits = [
        const("s_r_values", values),
        const("s_r_positions", positions[:, None]),
        const("s_r_size", np.array([flat.size], dtype=np.int64)),
        const("s_r_shape", np.array(counts.shape, dtype=np.int64)),
    ]
    nodes = [
        helper.make_node(
            "ConstantOfShape", ["s_r_size"], ["s_r_zeros"], value=numpy_helper.from_array(np.zeros(1, dtype=np.float64))
        ),
        helper.make_node("Cast", ["s_r_values"], ["s_r_nonzero"], to=TensorProto.DOUBLE),
        helper.make_node("Cast", ["s_r_positions"], ["s_r_index"], to=TensorProto.INT64),
        helper.make_node("ScatterND", ["s_r_zeros", "s_r_index", "s_r_nonzero"], ["s_r_flat"]),
        helper.make_node("Reshape", ["s_r_flat", "s_r_shape"], ["s_r"]),
    ]
    return nodes, inits


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


def readout_matrix_nodes(model: FixedPointModel, matrix: np.ndarray) -> tuple[list[onnx.NodeProto], list[TensorProto]]:
    """``s_r``, ``s_double_prime`` and ``inv_colsum`` (float64) from the integer counts S^R (eq. 9-10).

    omega_i = #{l : S^R_il > 0};  S'_il = S^R_il / omega_i where omega_i > gamma places, else S^R_il
    S''_il  = S'_il (S^R_il / sum_m S^R_im)  (a silent row is 0);  inv_colsum_l = 1 / sum_i S^R_il, 0 where 0
    Each is one correctly rounded float64 operation on exact integers, as in weighted_matrix.
    ``matrix``: the S^R the readout uses (:func:`readout_calibration`).
    """
    n_places = model.calibration.shape[1]
    if np.array_equal(matrix, np.round(matrix)):  # counts (a single network, lambda 0 or 1): stored exactly as integers
        nodes, inits = calibration_nodes(np.round(matrix).astype(np.int64))
    else:
        nodes, inits = [helper.make_node("Identity", ["s_r_weighted"], ["s_r"])], [const("s_r_weighted", matrix)]
    inits += [
        const("involvement", np.float64(float(model.config.assignment.gamma) * n_places)),
        const("axis0_outer", np.array([0], dtype=np.int64)),
        const("f_zero", np.float64(0.0)),
        const("f_one", np.float64(1.0)),
        const("axis1_outer", np.array([1], dtype=np.int64)),
    ]
    nodes += [
        helper.make_node("Greater", ["s_r", "f_zero"], ["s_r_positive"]),
        helper.make_node("Cast", ["s_r_positive"], ["s_r_involved"], to=TensorProto.DOUBLE),
        helper.make_node("ReduceSum", ["s_r_involved", "axis1_outer"], ["omega"], keepdims=1),
        helper.make_node("Greater", ["omega", "involvement"], ["penalised"]),
        helper.make_node("Where", ["penalised", "omega", "f_one"], ["divisor"]),
        helper.make_node("Div", ["s_r", "divisor"], ["s_prime"]),
        helper.make_node("ReduceSum", ["s_r", "axis1_outer"], ["rowsum"], keepdims=1),
        helper.make_node("Greater", ["rowsum", "f_zero"], ["row_active"]),
        helper.make_node("Where", ["row_active", "rowsum", "f_one"], ["row_safe"]),
        helper.make_node("Div", ["s_r", "row_safe"], ["row_share"]),
        helper.make_node("Mul", ["s_prime", "row_share"], ["s_double_prime"]),
        helper.make_node("ReduceSum", ["s_r", "axis0_outer"], ["colsum"], keepdims=1),
        helper.make_node("Greater", ["colsum", "f_zero"], ["col_active"]),
        helper.make_node("Where", ["col_active", "colsum", "f_one"], ["col_safe"]),
        helper.make_node("Div", ["f_one", "col_safe"], ["col_inverse"]),
        helper.make_node("Where", ["col_active", "col_inverse", "f_zero"], ["inv_colsum"]),
    ]
    return nodes, inits


def wprob_nodes(model: FixedPointModel) -> tuple[list[onnx.NodeProto], list[TensorProto]]:
    """P(l | Q) from counts: eq. 9-11 scores, min-max normalised, L1 normalised (eq. 12-13).

    An ensemble's head reads out with its region regularisation (:func:`readout_calibration`).

    scores = (S^Q S'') * (([S^Q > 0] S^R) / colsum(S^R)),  0 where colsum = 0
    P      = (scores - min) / (max - min) / sum(...),     uniform where max == min
    """
    n_places = model.calibration.shape[1]
    matrix, keep = readout_calibration(model)
    nodes, inits = readout_matrix_nodes(model, matrix)
    inits += [
        const("uniform", np.float64(1.0 / n_places)),
        const("i_zero", np.int64(0)),
    ]
    head_counts = "counts"
    if keep is not None:  # an ensemble: the silenced neurons' counts do not reach the readout
        inits.append(const("readout_keep", keep.astype(np.int64)))
        nodes.append(helper.make_node("Mul", ["counts", "readout_keep"], ["readout_counts"]))
        head_counts = "readout_counts"
    nodes += [
        helper.make_node("Cast", [head_counts], ["sq"], to=TensorProto.DOUBLE),
        helper.make_node("MatMul", ["sq", "s_double_prime"], ["raw"]),
        helper.make_node("Greater", [head_counts, "i_zero"], ["active_b"]),
        helper.make_node("Cast", ["active_b"], ["active"], to=TensorProto.DOUBLE),
        helper.make_node("MatMul", ["active", "s_r"], ["covered"]),
        helper.make_node("Mul", ["covered", "inv_colsum"], ["penalty"]),
        helper.make_node("Mul", ["raw", "penalty"], ["scores"]),
        helper.make_node("ReduceMin", ["scores", "axis1_outer"], ["lo"], keepdims=1),
        helper.make_node("ReduceMax", ["scores", "axis1_outer"], ["hi"], keepdims=1),
        helper.make_node("Sub", ["hi", "lo"], ["span"]),
        helper.make_node("Greater", ["span", "f_zero"], ["spread"]),
        helper.make_node("Where", ["spread", "span", "f_one"], ["span_safe"]),
        helper.make_node("Sub", ["scores", "lo"], ["shifted"]),
        helper.make_node("Div", ["shifted", "span_safe"], ["norm"]),
        helper.make_node("ReduceSum", ["norm", "axis1_outer"], ["total"], keepdims=1),
        helper.make_node("Greater", ["total", "f_zero"], ["positive"]),
        helper.make_node("Where", ["positive", "total", "f_one"], ["total_safe"]),
        helper.make_node("Div", ["norm", "total_safe"], ["dist"]),
        helper.make_node("Where", ["spread", "dist", "uniform"], ["wprob"]),
    ]
    return nodes, inits


def build_onnx(model: FixedPointModel, *, with_wprob: bool = True, with_raster: bool = False) -> onnx.ModelProto:
    """The ONNX model of ``model``'s integer inference (see the module docstring)."""
    check_exportable(model)
    n, timesteps = model.n_neurons, model.config.encoder.timesteps
    nodes, inits = currents_nodes(model)
    per_neuron, per_neuron_inits = neuron_nodes(model)
    nodes += per_neuron
    inits += per_neuron_inits
    scan_outputs = ["v_final", "counts", "saturations"] + (["raster"] if with_raster else [])
    nodes.append(
        helper.make_node(
            "Scan",
            ["v0", "v0", "sat0", "currents"],
            scan_outputs,
            body=step_body(model, with_raster),
            num_scan_inputs=1,
        )
    )
    outputs = [
        helper.make_tensor_value_info("counts", TensorProto.INT64, ["batch", n]),
        helper.make_tensor_value_info("saturations", TensorProto.INT64, ["batch"]),
    ]
    if with_wprob:
        head, head_inits = wprob_nodes(model)
        nodes += head
        inits += head_inits
        outputs.append(
            helper.make_tensor_value_info("wprob", TensorProto.DOUBLE, ["batch", model.calibration.shape[1]])
        )
    if with_raster:
        outputs.append(helper.make_tensor_value_info("raster", TensorProto.BOOL, [timesteps, "batch", n]))
    graph = helper.make_graph(
        nodes,
        "vprsnn_integer_inference",
        [
            helper.make_tensor_value_info(
                INPUT,
                TensorProto.UINT8,
                [timesteps, "batch", model.n_inputs],
                doc_string=input_layout(model),
                shape_denotation=list(INPUT_DENOTATION),
            )
        ],
        outputs,
        inits,
    )
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


def input_layout(model: FixedPointModel) -> str:
    """The ``spikes`` input's layout in words (its doc_string and the ``vprsnn.input_layout`` property)."""
    timesteps = model.config.encoder.timesteps
    return (
        f"spikes [T = {timesteps}, batch, inputs = {model.n_inputs}] uint8 0/1, time first: presentations held as "
        f"(batch, T, inputs) are fed as x.transpose(1, 0, 2); onnxruntime refuses another T or width"
    )


def metadata_props(model: FixedPointModel, *, with_wprob: bool = True) -> dict[str, str]:
    """Key facts as ONNX metadata_props (strings): widths, scales, encoder, T, source hash, and what a user needs
    to decide without the project: reference place ids, input layout, encoder contract, decision rule (JSON)."""
    cfg = model.config
    standalone = {
        "vprsnn.reference_place_ids": as_json(model.reference_place_ids.astype(int).tolist()),
        "vprsnn.input_layout": input_layout(model),
        "vprsnn.encoder_contract": as_json(encoder_contract(cfg)),
    }
    if with_wprob:
        standalone["vprsnn.decision"] = as_json(decision_rule("wprob"))
    return {
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
        **standalone,
    }


def write_onnx(model: FixedPointModel, path: str | Path, *, with_wprob: bool = True, with_raster: bool = False) -> Path:
    """Build, check and write the graph atomically."""
    data = build_onnx(model, with_wprob=with_wprob, with_raster=with_raster).SerializeToString()
    return atomic_write_bytes(path, data)
