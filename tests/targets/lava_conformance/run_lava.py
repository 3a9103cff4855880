"""Run an exported Loihi description in Lava itself (lava-nc 0.10, Python 3.10), WTA off.

Usage (inside the Lava venv):  python run_lava.py [--netx] DESCRIPTION_DIR SPIKES.npy RASTER_OUT.npy

Reads only network.json and network.npz (numpy + json, no vprsnn-export import; it unpacks
the bit-packed weight mantissas of format version 2 itself), builds

    RingBuffer(spikes) -> Dense(weights, num_weight_bits, weight_exp, EXCITATORY) -> LIF(du, dv, vth) -> RingBuffer sink

and runs it with Loihi2SimCfg(select_tag="fixed_pt"), Lava's bit-accurate CPU models.
Each presentation is one block of T + 1 steps: the Dense process delivers step t's
activation at step t + 1, so a silent input step at the end of every block flushes it;
exc.v and exc.u are set to 0 before every block (state isolation). The LIF raster of
block steps 1..T is presentation steps 0..T-1. Writes the raster (N, T, neurons) as uint8.

With --netx it loads network.net with lava-dl's netx (lava.lib.dl.netx.hdf5.Network, lava-dl
0.6) instead and runs the same blocks through it (netx builds its own Dense + LIF).
"""

import json
import sys
from pathlib import Path

import numpy as np
from lava.magma.core.run_conditions import RunSteps
from lava.magma.core.run_configs import Loihi2SimCfg
from lava.proc.dense.process import Dense
from lava.proc.io.sink import RingBuffer as SpikeSink
from lava.proc.io.source import RingBuffer as SpikeSource
from lava.proc.lif.process import LIF
from lava.utils.weightutils import SignMode


def load(folder):
    header = json.loads((Path(folder) / "network.json").read_text())
    with np.load(Path(folder) / header["arrays"]["file"]) as npz:
        arrays = {name: npz[name] for name in npz.files}
    return header, arrays


def unpack_bits(packed, bits, shape):
    """The header's "lsb-first-bitstream": value k = sum_i bit(k bits + i) 2**i, stream bit n = bit n % 8 of byte n // 8."""
    count = int(np.prod(shape))
    plane = np.unpackbits(packed, bitorder="little")[: count * bits].reshape(count, bits).astype(np.int32)
    return (plane << np.arange(bits)).sum(axis=1).reshape(shape)


def dense_weights(header, arrays):
    """Dense.weights (neurons, inputs): version 1 stores them, version 2 the packed mantissas q (w = q << shift)."""
    conn = header["connections"][0]
    if header["format_version"] == 1:
        return arrays[conn["weights"]]
    storage = conn["weights_storage"]
    assert storage["packing"] == "lsb-first-bitstream", storage["packing"]
    q = unpack_bits(arrays[conn["weights"]], storage["bits"], tuple(storage["shape"]))
    return q << -conn["weight_exp"]


def source_data(spikes):
    """(N, T, inputs) -> (inputs, N (T + 1)): each presentation followed by one silent step."""
    n, timesteps, n_inputs = spikes.shape
    padded = np.zeros((n, timesteps + 1, n_inputs), dtype=np.int32)
    padded[:, :timesteps] = spikes
    return padded.reshape(n * (timesteps + 1), n_inputs).T.copy()


def main(folder, spikes_path, out_path):
    header, arrays = load(folder)
    exc = header["populations"][1]
    conn = header["connections"][0]
    spikes = np.load(spikes_path)
    n, timesteps, _ = spikes.shape
    block = timesteps + 1
    neurons = exc["size"]
    source = SpikeSource(data=source_data(spikes))
    dense = Dense(
        weights=dense_weights(header, arrays),
        num_weight_bits=conn["num_weight_bits"],
        weight_exp=conn["weight_exp"],
        sign_mode=SignMode(conn["sign_mode_value"]),
    )
    lif = LIF(
        shape=(neurons,),
        du=exc["du"],
        dv=exc["dv"],
        vth=arrays[exc["vth"]],
        bias_mant=arrays[exc["bias_mant"]],
        bias_exp=exc["bias_exp"],
    )
    sink = SpikeSink(shape=(neurons,), buffer=n * block)
    source.s_out.connect(dense.s_in)
    dense.a_out.connect(lif.a_in)
    lif.s_out.connect(sink.a_in)
    config = Loihi2SimCfg(select_tag="fixed_pt")
    zeros = np.zeros(neurons)
    try:
        for _ in range(n):
            lif.run(condition=RunSteps(num_steps=block), run_cfg=config)
            lif.v.set(zeros)
            lif.u.set(zeros)
        data = sink.data.get()
    finally:
        lif.stop()
    raster = data.T.reshape(n, block, neurons)[:, 1:, :]
    np.save(out_path, raster.astype(np.uint8))


def main_netx(folder, spikes_path, out_path):
    """The same blocks through lava-dl's netx: network.net loaded by lava.lib.dl.netx.hdf5.Network."""
    from lava.lib.dl.netx.hdf5 import Network

    spikes = np.load(spikes_path)
    n, timesteps, _ = spikes.shape
    block = timesteps + 1
    net = Network(net_config=str(Path(folder) / "network.net"))
    neuron = net.layers[0].neuron
    neurons = net.out.shape[0]
    source = SpikeSource(data=source_data(spikes))
    sink = SpikeSink(shape=(neurons,), buffer=n * block)
    source.s_out.connect(net.inp)
    net.out.connect(sink.a_in)
    config = Loihi2SimCfg(select_tag="fixed_pt")
    zeros = np.zeros(neurons)
    try:
        for _ in range(n):
            net.run(condition=RunSteps(num_steps=block), run_cfg=config)
            neuron.v.set(zeros)
            neuron.u.set(zeros)
        data = sink.data.get()
    finally:
        net.stop()
    raster = data.T.reshape(n, block, neurons)[:, 1:, :]
    np.save(out_path, raster.astype(np.uint8))


if __name__ == "__main__":
    if sys.argv[1] == "--netx":
        main_netx(*sys.argv[2:5])
    else:
        main(*sys.argv[1:4])
