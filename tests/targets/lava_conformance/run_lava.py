"""Run an exported Loihi description in Lava itself (lava-nc 0.10, Python 3.10), WTA off or on.

Usage (inside the Lava venv):

    python run_lava.py [--netx] DESCRIPTION_DIR SPIKES.npy RASTER_OUT.npy
    python run_lava.py --wta DESCRIPTION_DIR SPIKES.npy RASTER_OUT.npy [CANDIDATES_OUT.npy]

Reads only network.json and network.npz (numpy + json, no vprsnn-export import; it unpacks
the bit-packed weight mantissas of format version 2 itself), builds

    RingBuffer(spikes) -> Dense(weights, num_weight_bits, weight_exp, EXCITATORY) -> LIF(du, dv, vth) -> RingBuffer sink

and runs it with Loihi2SimCfg(select_tag="fixed_pt"), Lava's bit-accurate CPU models.
Each presentation is one block of T + 1 steps: the Dense process delivers step t's
activation at step t + 1, so a silent input step at the end of every block flushes it;
exc.v and exc.u are set to 0 before every block (state isolation). The LIF raster of
block steps 1..T is presentation steps 0..T-1. Writes the raster (N, T, neurons) as uint8.

With --wta the network gets the header's hard WTA as one more Lava process, WtaReadout:

    Dense.a_out -> LIF.a_in, Dense.a_out -> WtaReadout.a_in, LIF.s_out -> WtaReadout.s_in,
    WtaReadout.s_out -> RingBuffer sink

Lava's LIF (WTA off) gives the candidates C[t] (every candidate resets, so its voltages are
the WTA-on network's); the readout emits S_j[t] = 1 for the j in C[t] with the largest
a_j[t] * m_j (ties to the lowest index), m_j the header's wta score multiplier, within every
group of the header's wta.group_size consecutive neurons (one module of an ensemble). Dense sends
the current a[t] at Lava step t + 1, where the LIF integrates it and spikes, and ports
between processes add no delay, so the readout receives the current and the candidates of
the same presentation step in the same Lava step. RASTER_OUT gets the WTA-on raster,
CANDIDATES_OUT (optional) the LIF's WTA-off raster of the same run.

With --netx it loads network.net with lava-dl's netx (lava.lib.dl.netx.hdf5.Network, lava-dl
0.6) instead and runs the same blocks through it (netx builds its own Dense + LIF).
"""

import json
import sys
from pathlib import Path

import numpy as np
from lava.magma.core.decorator import implements, requires, tag
from lava.magma.core.model.py.model import PyLoihiProcessModel
from lava.magma.core.model.py.ports import PyInPort, PyOutPort
from lava.magma.core.model.py.type import LavaPyType
from lava.magma.core.process.ports.ports import InPort, OutPort
from lava.magma.core.process.process import AbstractProcess
from lava.magma.core.process.variable import Var
from lava.magma.core.resources import CPU
from lava.magma.core.run_conditions import RunSteps
from lava.magma.core.run_configs import Loihi2SimCfg
from lava.magma.core.sync.protocols.loihi_protocol import LoihiProtocol
from lava.proc.dense.process import Dense
from lava.proc.io.sink import RingBuffer as SpikeSink
from lava.proc.io.source import RingBuffer as SpikeSource
from lava.proc.lif.process import LIF
from lava.utils.weightutils import SignMode


class WtaReadout(AbstractProcess):
    """Hard WTA after the LIF: of the step's spiking neurons (s_in) forward only the one with the largest a_j * m_j.

    s_in: the LIF's spikes (the candidates), a_in: the Dense activation a_j of the same step,
    s_out: one spike (or none) per step; score_multiplier: m_j, the header's wta_score_multiplier.
    """

    def __init__(self, *, score_multiplier, group_size=None):
        shape = (len(score_multiplier),)
        super().__init__(shape=shape)
        self.s_in = InPort(shape=shape)
        self.a_in = InPort(shape=shape)
        self.s_out = OutPort(shape=shape)
        self.score_multiplier = Var(shape=shape, init=np.asarray(score_multiplier, dtype=np.int32))
        self.group_size = Var(shape=(1,), init=np.array([group_size or shape[0]], dtype=np.int32))


def wta_winners(candidates, current, multiplier, group_size):
    """Per group of group_size neurons (one module), one-hot of argmax_j over C of a_j m_j (int64: exact for
    int32 a_j and m_j), first index on ties; zeros in a group with no candidate."""
    score = np.where(candidates != 0, current.astype(np.int64) * multiplier.astype(np.int64), -1).reshape(-1, group_size)
    out = np.zeros(score.shape, dtype=np.int32)
    rows = np.flatnonzero(score.max(axis=1) >= 0)
    out[rows, np.argmax(score[rows], axis=1)] = 1
    return out.reshape(candidates.shape)


@implements(proc=WtaReadout, protocol=LoihiProtocol)
@requires(CPU)
@tag("fixed_pt")
class PyWtaReadoutModelFixed(PyLoihiProcessModel):
    """Integer model of WtaReadout: a_j m_j in int64, np.argmax's first maximum is the lowest index."""

    s_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.int32, precision=24)
    a_in: PyInPort = LavaPyType(PyInPort.VEC_DENSE, np.int32, precision=24)
    s_out: PyOutPort = LavaPyType(PyOutPort.VEC_DENSE, np.int32, precision=1)
    score_multiplier: np.ndarray = LavaPyType(np.ndarray, np.int32, precision=32)
    group_size: np.ndarray = LavaPyType(np.ndarray, np.int32, precision=32)

    def run_spk(self):
        group = int(self.group_size[0])
        self.s_out.send(wta_winners(self.s_in.recv(), self.a_in.recv(), self.score_multiplier, group))


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


def main(folder, spikes_path, out_path, wta=False, candidates_path=None):
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
    if wta:
        readout = WtaReadout(
            score_multiplier=arrays[header["wta"]["score_multiplier"]], group_size=header["wta"].get("group_size")
        )
        winners = SpikeSink(shape=(neurons,), buffer=n * block)
        dense.a_out.connect(readout.a_in)
        lif.s_out.connect(readout.s_in)
        readout.s_out.connect(winners.a_in)
    config = Loihi2SimCfg(select_tag="fixed_pt")
    zeros = np.zeros(neurons)
    try:
        for _ in range(n):
            lif.run(condition=RunSteps(num_steps=block), run_cfg=config)
            lif.v.set(zeros)
            lif.u.set(zeros)
        data = sink.data.get()
        winner_data = winners.data.get() if wta else None
    finally:
        lif.stop()
    if wta:
        np.save(out_path, block_raster(winner_data, n, block, neurons))
        if candidates_path is not None:
            np.save(candidates_path, block_raster(data, n, block, neurons))
    else:
        np.save(out_path, block_raster(data, n, block, neurons))


def block_raster(data, n, block, neurons):
    """A sink's (neurons, N (T + 1)) buffer -> (N, T, neurons) uint8: block steps 1..T are presentation steps 0..T-1."""
    return data.T.reshape(n, block, neurons)[:, 1:, :].astype(np.uint8)


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
    np.save(out_path, block_raster(data, n, block, neurons))


if __name__ == "__main__":
    if sys.argv[1] == "--netx":
        main_netx(*sys.argv[2:5])
    elif sys.argv[1] == "--wta":
        main(*sys.argv[2:5], wta=True, candidates_path=sys.argv[5] if len(sys.argv) > 5 else None)
    else:
        main(*sys.argv[1:4])
