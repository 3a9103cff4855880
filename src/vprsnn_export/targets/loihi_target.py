"""The deployed network as Loihi-convention fixed-point parameters (Lava's `fixed_pt` models).

Written into one folder:

    network.json   header: populations, connections, neuron parameters, WTA rule, input
                   source, timing, arithmetic, and the fixed-point model's own header
    network.npz    arrays named in the header (no pickle), sha256 recorded in the header; the
                   weight mantissas bit-packed, ``bits`` bits each (:mod:`targets.packing`,
                   the layout stated in the header's ``weights_storage``)
    network.net    lava-dl netx HDF5 (one dense CUBA layer, vThMant per neuron or one value)

Mapping (Lava `Dense` + `LIF`, bit-accurate models, per step):

    Dense:  weights w_ji = q_ij << (8 - bits) (8-bit mantissas, sign mode EXCITATORY),
            num_weight_bits = bits, weight_exp = -(8 - bits), so
            a_j = (sum_i w_ji s_i) >> (8 - bits) = sum_i q_ij s_i exactly; one step of delay
    LIF:    du = 4095 (u = a << 6 each step), dv = decay_dv, vth = theta_int_j (17 bits, << 6),
            bias_mant = 0, bias_exp = 0; v = clip(trunc0(v (4096 - dv) / 4096) + u), spike when
            v > vth << 6, v <- 0

Lava's LIF wraps u at 24 bits where the contract saturates v; the two agree while
a_j << 6 < 2**23, i.e. a_j < 131072 (the header's ``current_bound`` says whether the
model can reach it). Hard WTA is not expressible with Dense and LIF: the header describes
the rule as a readout after the LIF population (it only selects which candidate's spike is
emitted; every candidate still resets, so the LIF dynamics are the WTA-off ones), and
``tests/targets/lava_conformance/run_lava.py --wta`` implements it as a Lava process
(``WtaReadout``) fed by the LIF spikes and the Dense current.

Ensembles: the M modules share the input and never interact, so ``exc`` stays one LIF of M n
neurons (one (M n, inputs) matrix) and the header lists each module's population ``exc_m``, with
its own WTA (``wta.group_size`` = n); :mod:`.loihi_budget` counts the cores they need.

Header and arrays: :mod:`.loihi_description`; network.net: :mod:`.loihi_netx`; this module writes
the folder and reads it back.
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from vprsnn_export.errors import InvalidValueError, ModelFileError, VprError
from vprsnn_export.export.model import MODEL_ARRAYS, FixedPointModel, model_from_header
from vprsnn_export.io.fileio import atomic_write_bytes, atomic_write_text, parse_json, sha256_bytes
from vprsnn_export.targets.loihi_description import (
    ARRAYS_NAME,
    DU_NO_CURRENT_MEMORY,
    FORMAT,
    HEADER_NAME,
    NETX_NAME,
    OTHER_ARRAYS,
    READABLE_VERSIONS,
    WEIGHTS_NAME,
    WEIGHTS_NAME_V1,
    LoihiDescription,
    describe,
    mantissas_from_lava,
)
from vprsnn_export.targets.loihi_netx import write_netx
from vprsnn_export.targets.packing import PACKING, unpack_bits


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    members: dict[str, Any] = dict(arrays)
    np.savez_compressed(buffer, **members)
    return buffer.getvalue()


def write_loihi(model: FixedPointModel, out_dir: str | Path, *, source_sha256: str | None = None) -> dict[str, Path]:
    """Write network.json, network.npz and network.net into ``out_dir``.

    The arrays go first and the header, which names their sha256, last: a reader never sees
    a header pointing at arrays that are not there yet.
    """
    out_dir = Path(out_dir)
    desc = describe(model, source_sha256=source_sha256)
    blob = npz_bytes(desc.arrays)
    desc.header["arrays"] = {"file": ARRAYS_NAME, "sha256": sha256_bytes(blob)}
    written = {"arrays": atomic_write_bytes(out_dir / ARRAYS_NAME, blob)}
    written["netx"] = write_netx(model, out_dir / NETX_NAME)
    written["header"] = atomic_write_text(out_dir / HEADER_NAME, json.dumps(desc.header, indent=2, sort_keys=True))
    return written


def header_path(path: str | Path) -> Path:
    path = Path(path)
    return path / HEADER_NAME if path.is_dir() else path


def arrays_file(head: Path, header: dict) -> Path:
    """The arrays file the header names, in network.json's folder: a bare file name (no folder, no ``..``, not
    absolute; a symbolic link that leads out of the folder is refused too); ModelFileError otherwise."""
    arrays = header.get("arrays")
    name = arrays.get("file", ARRAYS_NAME) if isinstance(arrays, dict) else None
    if not isinstance(name, str) or not name or Path(name).name != name or name in (".", ".."):
        raise ModelFileError(f"the header's arrays file must be a file name in its folder, got {name!r}", head)
    path = head.parent / name
    try:
        inside = path.resolve().parent == head.parent.resolve()
    except (OSError, RuntimeError):
        inside = False
    if not inside:
        raise ModelFileError(f"the arrays file {name!r} resolves outside the description's folder", head)
    return path


def read_loihi(path: str | Path) -> LoihiDescription:
    """Read and check a description (its folder or its network.json); defects are ModelFileErrors."""
    head = header_path(path)
    if not head.is_file():
        raise ModelFileError("no Loihi description here (network.json missing)", head)
    try:
        header = parse_json(head.read_bytes(), "network.json")
    except (UnicodeDecodeError, json.JSONDecodeError, InvalidValueError) as exc:
        raise ModelFileError(f"the description header is not valid JSON (truncated or corrupt: {exc})", head) from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        found = header.get("format") if isinstance(header, dict) else None
        raise ModelFileError(f"not a vprsnn Loihi description (format {found!r})", head)
    version = header.get("format_version")
    if version not in READABLE_VERSIONS:
        raise ModelFileError(
            f"unsupported Loihi description version {version!r} (this version reads {list(READABLE_VERSIONS)})", head
        )
    arrays_path = arrays_file(head, header)
    if not arrays_path.is_file():
        raise ModelFileError("the arrays file named by the header is missing", arrays_path)
    blob = arrays_path.read_bytes()
    if sha256_bytes(blob) != header["arrays"].get("sha256"):
        raise ModelFileError(
            "the arrays file does not match the sha256 in network.json (truncated or replaced)", arrays_path
        )
    try:
        with np.load(io.BytesIO(blob), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except (ValueError, OSError, EOFError, KeyError) as exc:
        raise ModelFileError(f"unreadable arrays ({exc})", arrays_path) from None
    needed = (WEIGHTS_NAME if version == 2 else WEIGHTS_NAME_V1, *OTHER_ARRAYS)
    if missing := sorted(set(needed) - set(arrays)):
        raise ModelFileError(f"the arrays file lacks {missing}", arrays_path)
    desc = LoihiDescription(header=header, arrays=arrays)
    try:
        lava_weight_matrix(desc)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise ModelFileError(f"the weights cannot be read ({type(exc).__name__}: {exc})", arrays_path) from None
    return desc


def lava_weight_matrix(desc: LoihiDescription) -> np.ndarray:
    """Lava's ``Dense.weights`` (neurons, inputs) int32 = q << -weight_exp, unpacked from either format version.

    Version 2 stores the mantissas q packed as its ``weights_storage`` states; version 1
    stored these weights as they are. A storage that does not match the header is a ValueError.
    """
    conn = desc.header["connections"][0]
    stored = desc.arrays[conn["weights"]]
    if desc.header.get("format_version") == 1:
        return stored.astype(np.int32)
    storage = conn["weights_storage"]
    bits, shape = int(storage["bits"]), tuple(int(n) for n in storage["shape"])
    if storage.get("packing") != PACKING or bits != int(conn["num_weight_bits"]):
        raise InvalidValueError(
            f"weights_storage must be {PACKING!r} at num_weight_bits = {conn['num_weight_bits']}, "
            f"got {storage.get('packing')!r} at {bits} bits"
        )
    mantissas = unpack_bits(stored, bits, shape).astype(np.int32)
    return mantissas << -int(conn["weight_exp"])


def read_loihi_model(path: str | Path) -> FixedPointModel:
    """:func:`read_loihi`, then the fixed-point model rebuilt from its Lava parameters (the export's round trip)."""
    desc, path = read_loihi(path), header_path(path)
    try:
        fixed = desc.header["fixed_point_model"]
        conn = desc.header["connections"][0]
        exc = desc.header["populations"][1]
        arrays = {
            "weight_mantissa": mantissas_from_lava(lava_weight_matrix(desc), int(conn["weight_exp"])),
            "scale_multiplier": desc.arrays["wta_score_multiplier"].astype(np.int32),
            "threshold": desc.arrays["exc_vth"].astype(np.int32),
            **{name: desc.arrays[name].astype(np.int64) for name in MODEL_ARRAYS[3:]},
        }
        lava = {"bits": int(conn["num_weight_bits"]), "decay_dv": int(exc["dv"])}  # in the Lava parameters' terms
        lava |= {"voltage_shift": int(exc["vth_shift"]), "voltage_bits": int(exc["u_v_bits"])}
        model = model_from_header(fixed, arrays, path, "Loihi description's fixed-point header", **lava)
    except (KeyError, IndexError, TypeError, ValueError, VprError) as exc_:
        raise ModelFileError(f"incomplete Loihi description ({type(exc_).__name__}: {exc_})", path) from None
    if int(exc["du"]) != DU_NO_CURRENT_MEMORY:  # dv: model_from_header validated it
        raise ModelFileError("du must be 4095 and dv a 12-bit decay", path)
    return model
