"""network.net: the fixed-point model as a lava-dl netx HDF5 file (one dense CUBA layer)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from vprsnn_export.export.model import FixedPointModel
from vprsnn_export.io.fileio import atomic_write_bytes
from vprsnn_export.targets.loihi_description import DU_NO_CURRENT_MEMORY


def write_netx(model: FixedPointModel, path: str | Path) -> Path:
    """lava-dl netx HDF5: ``layer/0`` a dense layer with a CUBA neuron, the mantissas as uint8 weights.

    The weight dataset is gzip-compressed (an HDF5 filter h5py reads transparently): about
    1.15 x bits per synapse at 2 and 4 bits instead of 8.

    netx maps CUBA to Lava's LIF with du = iDecay - 1, dv = vDecay and vth = vThMant (a
    scalar when every neuron shares the threshold, else the (neurons,) array, which Lava's
    LIF broadcasts), and re-derives num_weight_bits / weight_exp from the weights itself
    (exact for these non-negative integers).
    """
    import h5py

    uniform = bool(np.all(model.threshold == model.threshold[0]))
    vth = np.int64(model.threshold[0]) if uniform else model.threshold.astype(np.int64)

    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        layer = f.create_group("layer").create_group("0")
        layer.create_dataset("type", data=np.bytes_("dense"))
        layer.create_dataset("shape", data=np.array([model.n_neurons], dtype=np.int64))
        weight = model.weight_mantissa.T.astype(np.uint8)
        layer.create_dataset("weight", data=weight, compression="gzip", compression_opts=9, shuffle=False)
        neuron = layer.create_group("neuron")
        neuron.create_dataset("type", data=np.bytes_("CUBA"))
        neuron.create_dataset("iDecay", data=np.int64(DU_NO_CURRENT_MEMORY + 1))
        neuron.create_dataset("vDecay", data=np.int64(model.decay_dv))
        neuron.create_dataset("vThMant", data=vth)
        neuron.create_dataset("refDelay", data=np.int64(1))
        neuron.create_dataset("gradedSpike", data=np.bool_(False))
    return atomic_write_bytes(path, buffer.getvalue())
