"""Run an exported Loihi description in Lava itself (lava-nc 0.10, Python 3.10), WTA off.

Usage (inside the Lava venv):  python run_lava.py DESCRIPTION_DIR SPIKES.npy RASTER_OUT.npy

Reads only network.json and network.npz (numpy + json, no vprsnn-export import), builds

    RingBuffer(spikes) -> Dense(weights, num_weight_bits, weight_exp, EXCITATORY) -> LIF(du, dv, vth) -> RingBuffer sink

and runs it with Loihi2SimCfg(select_tag="fixed_pt"), Lava's bit-accurate CPU models.
Each presentation is one block of T + 1 steps: the Dense process delivers step t's
activation at step t + 1, so a silent input step at the end of every block flushes it;
exc.v and exc.u are set to 0 before every block (state isolation). The LIF raster of
block steps 1..T is presentation steps 0..T-1. Writes the raster (N, T, neurons) as uint8.
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
        weights=arrays[conn["weights"]],
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


if __name__ == "__main__":
    main(*sys.argv[1:4])
