"""Bad-input campaign over all nine `vprsnn-export` commands (issue 12), the library and faults (issue 24), reproducible.

Builds tiny fixtures once in a temp folder (a checkpoint trained for one epoch on
``synthetic:10``, 8- and 2-bit models, an export, a verify report, tampered copies of each,
small place manifests made from a few Nordland images, or generated ones when the shared data
is absent), then runs every case of :func:`all_cases`: bad inputs, which must stop with one
line ``error: ...`` and exit 2, and legal extremes, which must run. Run from the repository
root, with the project's virtual environment active:

    OMP_NUM_THREADS=1 python tools/bad_input_campaign.py --out build/campaign
    python tools/bad_input_campaign.py --out build/campaign --only velocity   # a subset
    python tools/bad_input_campaign.py --out build/campaign --exec            # every case a fresh process

Three sections (``--sections``, all by default): ``cli`` (the command lines above), ``api`` (the
public functions with bad arguments: tools/bad_input_api.py's cases, run in a child process so that
a crash is seen; a project error is ``clean``, any other exception ``traceback``, a file a save_*
function wrote that does not load ``write-then-refuse``, a bad value returned from ``accepted``
unless tools/bad_input_api.py lists it as legal, then ``ran``) and ``faults`` (SIGKILL while an
output is written: every file left visible loads, and the next run removes the temp; standard output
on /dev/full or a closed pipe: the conventional exit code and at most one line; Ctrl-C while the
command starts (once torch begins to load: before that, a SIGINT lands in CPython's own start-up or
pip's script wrapper, before any code of the project runs): exit 130 with one line; a broken check
is ``other``).

Each case runs in its own empty folder, with stdin from /dev/null, OMP_NUM_THREADS=1, a private
VPRSNN_CACHE and a timeout. By default a case is a child forked from this interpreter once it has
imported the CLI: the child redirects its file descriptors 0-2 and exits with
``sys.exit(vprsnn_export.cli.main())``'s status, as the ``vprsnn-export`` script does, without
2.5 s of imports per case. Every case that is not clean (or, for a legal extreme, did not run) is
run again as a real ``vprsnn-export`` process, and that result is the one reported (``--exec``:
every case that way, about 30 minutes).

Classes of a bad input: ``clean`` (exit 2, stderr exactly one line starting with ``error: ``),
``traceback`` (``Traceback`` in stderr), ``multi-line`` (non-zero exit with more than one stderr
line, an argparse usage block or an OpenCV warning), ``accepted`` (exit 0), ``timeout``,
``other``. A legal extreme: ``ran`` (an exit code it may give: 0, or 1 where a verification check
may fail) or the failure class (``refused`` for a clean error). Progress bars (tqdm) are not
counted as stderr lines. Writes OUT/bad_inputs.json and OUT/bad_inputs.md, prints one line per
case to stderr and the counts to stdout; exit status 0 when every bad input is clean and every
legal extreme ran, 1 otherwise.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import importlib
import importlib.util
import io
import json
import os
import pickle
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import zipfile
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
NORDLAND = ROOT.parent / "shared" / "data" / "nordland_64x32_summer_winter"
COMMANDS = ("train", "evaluate", "quantize", "simulate", "export", "verify", "report", "experiment", "demo", "localize")
SECTIONS = ("cli", "api", "faults")
API_TOOL = Path(__file__).resolve().with_name("bad_input_api.py")
BAD_CLASSES = ("clean", "traceback", "multi-line", "accepted", "write-then-refuse", "crash", "timeout", "other")
LEGAL_CLASSES = ("ran", "refused", "traceback", "multi-line", "timeout", "other")
TIMEOUT_S = 60.0  # the slowest legal extreme takes about 10 s

# Fixture paths as cases name them: {fx} is the fixture folder, {ro} a folder nothing can be written in.
CK = "{fx}/net.npz"
OTHER = "{fx}/other.npz"
EDGE = "{fx}/edge.npz"
M8 = "{fx}/models/model_8bit_per-neuron_max.npz"
M2 = "{fx}/models/model_2bit_per-neuron_max.npz"
NORD = "{fx}/nord/places.csv"
HUGE = "99999999999999999999"
TINY = ("--timesteps", "20", "--epochs", "1", "--neurons", "16")
TRAIN = ("train", "--data", "synthetic:10", "--reference", "summer", *TINY, "--out", "t.npz")
EVAL = ("evaluate", CK, "--query", "winter")
SIM = ("simulate", M8, "--query", "winter")
QUANT = ("quantize", CK, "--bits", "8", "--out", "q")
EXPORT = ("export", M8, "--out", "x")
VERIFY = ("verify", CK, "--bits", "8", "--query", "winter", "--report", "v")
EXPERIMENT = ("experiment", "assignment", "--quick", "--out", "e")
DEMO = ("demo", "--quick", "--out", "d")
#: The values every numeric option is tried with.
VALUES = {"nan": "nan", "inf": "inf", "neg": "-1", "zero": "0", "huge": HUGE, "text": "abc", "empty": ""}


@dataclass(frozen=True)
class Case:
    """One command line; ``copy`` fixtures are copied into its folder, ``links`` are (name, target) symlinks."""

    id: str
    argv: tuple[str, ...]
    legal: bool = False
    copy: tuple[str, ...] = ()  # fixture names ("rep", or "rep->rep2" to rename)
    links: tuple[tuple[str, str], ...] = ()
    ok_rc: tuple[int, ...] = (0,)
    note: str = ""
    says: str = ""  # a bad input: its error line must hold this (else "other": refused for another reason)
    check: str = ""  # a legal extreme: the OUTPUT_CHECKS entry its output must pass (else "other")

    @property
    def command(self) -> str:
        return self.argv[0] if self.argv and self.argv[0] in COMMANDS else "(none)"


@dataclass(frozen=True)
class Raw:
    """What one run gave: exit code, output, wall time."""

    rc: int
    stdout: str
    stderr: str
    seconds: float
    timed_out: bool


@dataclass(frozen=True)
class Outcome:
    """One case's classified result, as bad_inputs.json stores it."""

    id: str
    command: str
    line: str
    legal: bool
    klass: str
    rc: int
    first_line: str
    last_line: str
    seconds: float
    runner: str
    fork_class: str | None
    note: str
    stderr: str


def bad(case_id: str, *argv: str, **options: Any) -> Case:
    return Case(case_id, tuple(argv), **options)


def legal(case_id: str, *argv: str, **options: Any) -> Case:
    """A legal extreme; for verify, demo and export --check exit 1 (a check failed) also counts as ran."""
    checks = bool(argv) and (argv[0] in ("verify", "demo") or "--check" in argv)
    return Case(case_id, tuple(argv), legal=True, **{"ok_rc": (0, 1) if checks else (0,), **options})


# ---------------------------------------------------------------------------------------------- running


def exit_status(main: Callable[[], object]) -> int:
    """The exit status of ``sys.exit(main())`` in a fresh interpreter (an uncaught exception: traceback, 1)."""
    try:
        status: object = main()
    except SystemExit as exc:
        status = exc.code
    except BaseException:
        traceback.print_exc()
        return 1
    if status is None:
        return 0
    if isinstance(status, int):
        return status & 0xFF
    print(status, file=sys.stderr)
    return 1


def redirect(fd: int, path: str, flags: int) -> None:
    target = os.open(path, flags, 0o644)
    os.dup2(target, fd)
    os.close(target)


def forked_child(main: Callable[[], object], argv: Sequence[str], cwd: Path, out: Path, err: Path) -> NoReturn:
    """In the forked child: become ``vprsnn-export ARGV`` run in ``cwd``, then exit."""
    code = 1
    try:
        os.chdir(cwd)
        redirect(0, os.devnull, os.O_RDONLY)
        redirect(1, str(out), os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
        redirect(2, str(err), os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
        sys.argv = ["vprsnn-export", *argv]
        code = exit_status(main)
        atexit._run_exitfuncs()
    except BaseException:
        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)


def wait_child(pid: int, timeout: float) -> tuple[int, bool]:
    """Exit code of child ``pid`` (-signal when killed), and whether it ran past ``timeout`` (then killed)."""
    deadline = time.monotonic() + timeout
    timed_out = False
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status), timed_out
        if time.monotonic() > deadline and not timed_out:
            timed_out = True
            os.kill(pid, signal.SIGTERM)
            deadline = time.monotonic() + 5
        elif timed_out and time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            deadline = float("inf")
        time.sleep(0.005)


class ForkRunner:
    """Runs a case in a child forked from this interpreter after it imported the whole CLI."""

    name = "fork"

    def __init__(self, timeout: float, logs: Path) -> None:
        cli = importlib.import_module("vprsnn_export.cli")
        cli.build_parser()  # imports every command module (torch, numba, ...) once, here
        self.main: Callable[[], object] = cli.main
        self.timeout = timeout
        self.logs = logs

    def __call__(self, argv: Sequence[str], cwd: Path) -> Raw:
        out, err = self.logs / "stdout", self.logs / "stderr"
        sys.stdout.flush()
        sys.stderr.flush()
        started = time.perf_counter()
        pid = os.fork()
        if pid == 0:
            forked_child(self.main, argv, cwd, out, err)
        rc, timed_out = wait_child(pid, self.timeout)
        return Raw(rc, read_text(out), read_text(err), time.perf_counter() - started, timed_out)


class ExecRunner:
    """Runs a case as a real ``vprsnn-export`` process (its own session, killed on timeout)."""

    name = "exec"

    def __init__(self, timeout: float) -> None:
        found = shutil.which("vprsnn-export") or str(Path(sys.executable).with_name("vprsnn-export"))
        self.program = found
        self.timeout = timeout

    def __call__(self, argv: Sequence[str], cwd: Path) -> Raw:
        started = time.perf_counter()
        process = subprocess.Popen(
            [self.program, *argv],
            cwd=cwd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,
        )
        timed_out = False
        try:
            out, err = process.communicate(timeout=self.timeout)
        except subprocess.TimeoutExpired:
            timed_out = True
            os.killpg(process.pid, signal.SIGKILL)
            out, err = process.communicate()
        seconds = time.perf_counter() - started
        return Raw(process.returncode, decode(out), decode(err), seconds, timed_out)


Runner = ForkRunner | ExecRunner


def decode(data: bytes) -> str:
    return data.decode("utf-8", errors="replace")


def read_text(path: Path) -> str:
    return decode(path.read_bytes()) if path.exists() else ""


# ---------------------------------------------------------------------------------------------- classifying

OPENCV_WARNING = re.compile(r"\[ ?WARN:|libpng (warning|error)|global \S+\.cpp")
PROGRESS_BAR = re.compile(r"\d+%\||\d+(it|epoch|img|query|queries|step)s? \[")


def stderr_lines(stderr: str) -> list[str]:
    """The stderr lines a user reads: split at newlines and carriage returns, tqdm progress bars dropped."""
    return [piece for piece in re.split(r"[\r\n]", stderr) if piece.strip() and not PROGRESS_BAR.search(piece)]


def is_multi_line(stderr: str, lines: Sequence[str]) -> bool:
    usage = any(line.startswith("usage:") for line in lines)
    opencv = OPENCV_WARNING.search(stderr) is not None
    return len(lines) > 1 or usage or opencv


def classify(case: Case, raw: Raw) -> str:
    """The class of one outcome (see the module docstring)."""
    if raw.timed_out:
        return "timeout"
    if raw.rc < 0:  # killed by a signal: a segfault, an abort, the kernel's OOM killer
        return "crash"
    if "Traceback" in raw.stderr:
        return "traceback"
    if case.legal and raw.rc in case.ok_rc:
        return "ran"
    if not case.legal and raw.rc == 0:
        return "accepted"
    lines = stderr_lines(raw.stderr)
    if is_multi_line(raw.stderr, lines):
        return "multi-line"
    if raw.rc == 2 and len(lines) == 1 and lines[0].startswith("error: "):
        return "refused" if case.legal else "clean"
    return "other"


def is_finding(outcome: Outcome) -> bool:
    return outcome.klass != ("ran" if outcome.legal else "clean")


# ---------------------------------------------------------------------------------------------- fixtures


def read_npz(path: Path) -> tuple[Any, dict[str, np.ndarray]]:
    """JSON header and arrays of a project container."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    return json.loads(arrays.pop("__meta__").tobytes().decode("utf-8")), arrays


def write_npz(path: Path, meta: Any, arrays: Mapping[str, np.ndarray]) -> None:
    """A container with this header (any JSON value) and arrays; object arrays are pickled."""
    header = np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)
    members: dict[str, Any] = {"__meta__": header, **arrays}
    with open(path, "wb") as handle:
        np.savez(handle, **members)


def nested(meta: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """A deep copy of ``meta`` with the dotted key set (``None`` value: left as null)."""
    copy = json.loads(json.dumps(meta))
    *parents, key = dotted.split(".")
    target = copy
    for part in parents:
        target = target[part]
    target[key] = value
    return copy


def without(mapping: dict[str, Any], key: str) -> dict[str, Any]:
    return {k: v for k, v in mapping.items() if k != key}


Meta = Any
Arrays = dict[str, np.ndarray]
Edit = Callable[[Meta, Arrays], tuple[Meta, Arrays]]


def header(change: Callable[[Meta], Meta]) -> Edit:
    return lambda meta, arrays: (change(meta), arrays)


def array(change: Callable[[Arrays], Arrays]) -> Edit:
    return lambda meta, arrays: (meta, change(arrays))


def set_array(name: str, make: Callable[[np.ndarray], Any]) -> Edit:
    return array(lambda a: {**a, name: np.asarray(make(a[name]))})


#: Tampered checkpoints: a header or array edit of net.npz each.
CHECKPOINT_EDITS: dict[str, Edit] = {
    "header-list": header(lambda m: [m]),
    "header-string": header(lambda m: "summer"),
    "header-number": header(lambda m: 5),
    "format-other": header(lambda m: {**m, "format": "other"}),
    "format-version-99": header(lambda m: {**m, "format_version": 99}),
    "format-version-string": header(lambda m: {**m, "format_version": "1"}),
    "config-list": header(lambda m: {**m, "config": [1]}),
    "config-string": header(lambda m: {**m, "config": "paper"}),
    "config-null": header(lambda m: {**m, "config": None}),
    "config-missing": header(lambda m: without(m, "config")),
    "config-unknown-key": header(lambda m: nested(m, "config.nope", 1)),
    "section-list": header(lambda m: nested(m, "config.network", [1])),
    "section-string": header(lambda m: nested(m, "config.encoder", "x")),
    "seed-string": header(lambda m: nested({**m, "seed": "one"}, "config.seed", "one")),
    "seed-float": header(lambda m: nested({**m, "seed": 1.5}, "config.seed", 1.5)),
    "seed-negative": header(lambda m: nested({**m, "seed": -1}, "config.seed", -1)),
    "timesteps-null": header(lambda m: nested(m, "config.encoder.timesteps", None)),
    "timesteps-string": header(lambda m: nested(m, "config.encoder.timesteps", "20")),
    "timesteps-zero": header(lambda m: nested(m, "config.encoder.timesteps", 0)),
    "neurons-mismatch": header(lambda m: nested(m, "config.network.n_neurons", 17)),
    "module-size-mismatch": header(lambda m: nested(m, "config.train.module_size", 3)),
    "module-size-negative": header(lambda m: nested(m, "config.train.module_size", -2)),
    "beta-nan": header(lambda m: nested(m, "config.network.beta", float("nan"))),
    "gamma-infinity": header(lambda m: nested(m, "config.assignment.gamma", float("inf"))),
    "wta-string": header(lambda m: nested(m, "config.network.wta", "yes")),
    "channels-unknown": header(lambda m: nested(m, "config.preprocess.channels", "rgb")),
    "traversals-string": header(lambda m: {**m, "reference_traversals": "summer"}),
    "traversals-empty": header(lambda m: {**m, "reference_traversals": []}),
    "traversals-unknown": header(lambda m: {**m, "reference_traversals": ["autumn"]}),
    "traversals-numbers": header(lambda m: {**m, "reference_traversals": [1]}),
    "data-list": header(lambda m: {**m, "data": ["x"]}),
    "data-string": header(lambda m: {**m, "data": "synthetic:10"}),
    "data-source-missing": header(lambda m: nested(m, "data.source", "/nope/places.csv")),
    "data-source-number": header(lambda m: nested(m, "data.source", 5)),
    "data-source-huge": header(lambda m: nested(m, "data.source", "synthetic:100000000000")),
    "data-places-text": header(lambda m: nested(m, "data.places", "abc")),
    "history-mapping": header(lambda m: {**m, "history": {"a": 1}}),
    "history-strings": header(lambda m: {**m, "history": ["x"]}),
    "package-version-list": header(lambda m: {**m, "package_version": [1]}),
    "ref-ids-0d": set_array("reference_place_ids", lambda a: np.array(3)),
    "ref-ids-duplicate": set_array("reference_place_ids", np.zeros_like),
    "ref-ids-float": set_array("reference_place_ids", lambda a: a.astype(float) + 0.5),
    "ref-ids-negative": set_array("reference_place_ids", lambda a: -a - 1),
    "ref-ids-empty": set_array("reference_place_ids", lambda a: a[:0]),
    "ref-ids-2d": set_array("reference_place_ids", lambda a: a.reshape(1, -1)),
    "ref-ids-huge": set_array("reference_place_ids", lambda a: a + 10**18),
    "ref-ids-absent": set_array("reference_place_ids", lambda a: a + 50),
    "thresholds-zero": set_array("thresholds", np.zeros_like),
    "thresholds-negative": set_array("thresholds", lambda a: -a),
    "thresholds-nan": set_array("thresholds", lambda a: np.full_like(a, np.nan)),
    "thresholds-inf": set_array("thresholds", lambda a: np.full_like(a, np.inf)),
    "thresholds-int": set_array("thresholds", lambda a: np.ones(a.shape, dtype=np.int32)),
    "thresholds-0d": set_array("thresholds", lambda a: np.float32(1.5)),
    "thresholds-huge": set_array("thresholds", lambda a: np.full_like(a, 1e30)),
    "weights-huge": set_array("weights", lambda a: np.full_like(a, 1e30)),
    "weights-nan": set_array("weights", lambda a: np.full_like(a, np.nan)),
    "weights-negative": set_array("weights", lambda a: -a),
    "weights-shape": set_array("weights", lambda a: a[:10]),
    "weights-0d": set_array("weights", lambda a: np.float32(0.5)),
    "weights-int": set_array("weights", lambda a: np.zeros(a.shape, dtype=np.int64)),
    "weights-text": set_array("weights", lambda a: np.array(["a", "b"])),
    "weights-object": set_array("weights", lambda a: np.array([{"a": 1}], dtype=object)),
    "calibration-negative": set_array("calibration", lambda a: a - 100),
    "calibration-float": set_array("calibration", lambda a: a.astype(float) + 0.5),
    "calibration-shape": set_array("calibration", lambda a: a[:, :3]),
    "missing-weights": array(lambda a: without(a, "weights")),
    "missing-reference-ids": array(lambda a: without(a, "reference_place_ids")),
}

#: Tampered fixed-point models: edits of models/model_8bit_per-neuron_max.npz.
MODEL_EDITS: dict[str, Edit] = {
    "header-list": header(lambda m: [m]),
    "format-other": header(lambda m: {**m, "format": "vprsnn-checkpoint"}),
    "bits-text": header(lambda m: {**m, "bits": "eight"}),
    "bits-9": header(lambda m: {**m, "bits": 9}),
    "bits-null": header(lambda m: {**m, "bits": None}),
    "bits-float": header(lambda m: {**m, "bits": 8.5}),
    "bits-list": header(lambda m: {**m, "bits": [8]}),
    "scale-exponent-null": header(lambda m: {**m, "scale_exponent": None}),
    "scale-exponent-huge": header(lambda m: {**m, "scale_exponent": 10**30}),
    "scale-exponent-positive": header(lambda m: {**m, "scale_exponent": 40}),
    "decay-negative": header(lambda m: {**m, "decay_dv": -1}),
    "decay-float": header(lambda m: {**m, "decay_dv": 204.5}),
    "voltage-bits-16": header(lambda m: {**m, "voltage_bits": 16}),
    "voltage-shift-99": header(lambda m: {**m, "voltage_shift": 99}),
    "config-list": header(lambda m: {**m, "config": [1]}),
    "seed-string": header(lambda m: nested(m, "config.seed", "one")),
    "timesteps-null": header(lambda m: nested(m, "config.encoder.timesteps", None)),
    "neurons-mismatch": header(lambda m: nested(m, "config.network.n_neurons", 17)),
    "module-size-mismatch": header(lambda m: nested(m, "config.train.module_size", 3)),
    "quantisation-list": header(lambda m: {**m, "quantisation": [1]}),
    "quantisation-missing": header(lambda m: without(m, "quantisation")),
    "quantisation-bits-differ": header(lambda m: nested(m, "quantisation.bits", 2)),
    "source-sha-list": header(lambda m: {**m, "source_sha256": [1, 2]}),
    "source-sha-short": header(lambda m: {**m, "source_sha256": "abc"}),
    "data-list": header(lambda m: {**m, "data": ["x"]}),
    "data-source-number": header(lambda m: nested(m, "data.source", 5)),
    "traversals-string": header(lambda m: {**m, "reference_traversals": "summer"}),
    "traversals-empty": header(lambda m: {**m, "reference_traversals": []}),
    "traversals-numbers": header(lambda m: {**m, "reference_traversals": [1]}),
    "arithmetic-list": header(lambda m: {**m, "arithmetic": [1]}),
    "mantissa-out-of-range": set_array("weight_mantissa", lambda a: a + 1000),
    "mantissa-negative": set_array("weight_mantissa", lambda a: a - 1000),
    "mantissa-float": set_array("weight_mantissa", lambda a: a.astype(float)),
    "mantissa-shape": set_array("weight_mantissa", lambda a: a[:10]),
    "mantissa-0d": set_array("weight_mantissa", lambda a: np.int32(1)),
    "threshold-zero": set_array("threshold", np.zeros_like),
    "threshold-negative": set_array("threshold", lambda a: -a),
    "multiplier-zero": set_array("scale_multiplier", np.zeros_like),
    "calibration-negative": set_array("calibration", lambda a: a - 100),
    "calibration-float": set_array("calibration", lambda a: a.astype(float) + 0.5),
    "calibration-shape": set_array("calibration", lambda a: a[:, :3]),
    "float-calibration-shape": set_array("float_calibration", lambda a: a[:3]),
    "ref-ids-0d": set_array("reference_place_ids", lambda a: np.array(3)),
    "ref-ids-duplicate": set_array("reference_place_ids", np.zeros_like),
    "ref-ids-float": set_array("reference_place_ids", lambda a: a.astype(float) + 0.5),
    "missing-threshold": array(lambda a: without(a, "threshold")),
}

#: Tampered verify reports (report.json of the rep fixture).
REPORT_EDITS: dict[str, Callable[[Any], Any]] = {
    "list": lambda r: [r],
    "string": lambda r: "report",
    "empty-object": lambda r: {},
    "no-float-run": lambda r: {**r, "runs": [without(r["runs"][0], "float")]},
    "float-metrics-string": lambda r: {
        **r,
        "runs": [{**r["runs"][0], "float": {**r["runs"][0]["float"], "metrics": "x"}}],
    },
    "runs-empty": lambda r: {**r, "runs": []},
    "runs-string": lambda r: {**r, "runs": "x"},
    "runs-null": lambda r: {**r, "runs": None},
    "bits-empty": lambda r: {**r, "runs": [{**r["runs"][0], "bits": []}]},
    "bits-mapping": lambda r: {**r, "runs": [{**r["runs"][0], "bits": {"8": 1}}]},
    "schema-999": lambda r: {**r, "schema": "vprsnn-verify-report/999"},
    "schema-missing": lambda r: without(r, "schema"),
    "settings-list": lambda r: {**r, "settings": [1]},
    "summary-missing": lambda r: without(r, "summary"),
    "passed-string": lambda r: {**r, "passed": "yes"},
    "n-queries-string": lambda r: {**r, "runs": [{**r["runs"][0], "n_queries": "ten"}]},
    # values out of their range (issue 31): refused naming the file, never rendered
    "accuracy-5": lambda r: edit_metric(r, "accuracy", 5),
    "accuracy-neg": lambda r: edit_metric(r, "accuracy", -1),
    "accuracy-nan": lambda r: edit_metric(r, "accuracy", float("nan")),
    "bits-99": lambda r: {**r, "runs": [{**r["runs"][0], "bits": [{**r["runs"][0]["bits"][0], "bits": 99}]}]},
}
#: report.json with a line break in a stored string: renders, and no line of report.md is forged (issue 31).
REPORT_LEGAL_EDITS: dict[str, Callable[[Any], Any]] = {
    "label-newline": lambda r: {**r, "runs": [{**r["runs"][0], "label": "a\n# all checks passed"}]},
    "command-fence": lambda r: {**r, "command": ["vprsnn-export", "verify\n```\n# all checks passed\n```"]},
}


def edit_metric(report: Any, metric: str, value: float) -> Any:
    """``report`` with ``metric`` of the first run's first quantised readout set to ``value``."""
    run, result = report["runs"][0], report["runs"][0]["bits"][0]
    rows = [{**result["metrics"][0], metric: value}, *result["metrics"][1:]]
    return {**report, "runs": [{**run, "bits": [{**result, "metrics": rows}, *run["bits"][1:]]}]}


#: Byte-level defects written for checkpoints (ck_), models (fp_) alike.
RAW_DEFECTS = ("truncated", "bad-crc", "member-garbage", "header-not-json", "header-not-utf8", "no-header", "plain-npy")


def write_defect(kind: str, source: Path, target: Path) -> None:
    """A container with a byte-level defect of ``kind`` (see RAW_DEFECTS)."""
    meta, arrays = read_npz(source)
    members: dict[str, Any] = dict(arrays)
    if kind == "truncated":
        data = source.read_bytes()
        target.write_bytes(data[: len(data) // 2])
    elif kind == "bad-crc":
        write_npz(target, meta, arrays)
        flip_member_byte(target, "weights.npy" if "weights" in arrays else "weight_mantissa.npy")
    elif kind == "member-garbage":
        write_npz(target, meta, arrays)
        replace_member(target, "weights.npy" if "weights" in arrays else "weight_mantissa.npy", b"garbage")
    elif kind in ("header-not-json", "header-not-utf8"):
        raw = b"{not json" if kind == "header-not-json" else b"\xff\xfe\x00"
        with open(target, "wb") as handle:
            np.savez(handle, **{"__meta__": np.frombuffer(raw, dtype=np.uint8), **members})
    elif kind == "no-header":
        with open(target, "wb") as handle:
            np.savez(handle, **members)
    elif kind == "plain-npy":
        with open(target, "wb") as handle:
            np.save(handle, next(iter(arrays.values())))


def flip_member_byte(path: Path, member: str) -> None:
    """Corrupt one byte inside a stored zip member: its CRC no longer matches."""
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo(member)
    data = bytearray(path.read_bytes())
    name_length = int.from_bytes(data[info.header_offset + 26 : info.header_offset + 28], "little")
    extra_length = int.from_bytes(data[info.header_offset + 28 : info.header_offset + 30], "little")
    where = info.header_offset + 30 + name_length + extra_length + 200
    data[where] ^= 0xFF
    path.write_bytes(bytes(data))


def replace_member(path: Path, member: str, content: bytes) -> None:
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members[member] = content
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(name, data)


def write_tampered(fx: Path, source: Path, prefix: str, edits: Mapping[str, Edit]) -> None:
    meta, arrays = read_npz(source)
    for name, edit in edits.items():
        new_meta, new_arrays = edit(json.loads(json.dumps(meta)), dict(arrays))
        write_npz(fx / f"{prefix}_{name}.npz", new_meta, new_arrays)
    for kind in RAW_DEFECTS:
        write_defect(kind, source, fx / f"{prefix}_{kind}.npz")


def write_reports(fx: Path) -> None:
    """rp_NAME/ folders: the rep fixture with an edited report.json (and raw defects)."""
    source = fx / "rep" / "report.json"
    report = json.loads(source.read_text(encoding="utf-8"))
    edits = {**REPORT_EDITS, **REPORT_LEGAL_EDITS}
    texts = {name: json.dumps(edit(json.loads(json.dumps(report)))) for name, edit in edits.items()}
    texts["truncated"] = source.read_text(encoding="utf-8")[:500]
    texts["empty-file"] = ""
    for name, text in texts.items():
        folder = fx / f"rp_{name}"
        folder.mkdir()
        (folder / "report.json").write_text(text, encoding="utf-8")
    (fx / "rp_not-utf8").mkdir()
    (fx / "rp_not-utf8" / "report.json").write_bytes(b"\xff\xfe{")
    (fx / "rp_json-is-folder" / "report.json").mkdir(parents=True)


def nordland_rows(nordland: Path, count: int) -> list[tuple[Path, Path]]:
    """(summer, winter) image paths of ``count`` consecutive textured places of the shared data."""
    with open(nordland / "places.csv", encoding="utf-8") as handle:
        lines = handle.read().splitlines()[1:]
    rows = [line.split(",") for line in lines]
    chosen = [r for r in rows if r[6] == "0" and r[7] == "0"][100 : 100 + count]
    return [(nordland / r[2], nordland / r[3]) for r in chosen]


def write_images(folder: Path, nordland: Path | None, count: int) -> list[str]:
    """summer/ and winter/ PNGs of ``count`` places (Nordland copies, or generated); returns the file names."""
    cv2 = importlib.import_module("cv2")
    (folder / "summer").mkdir(parents=True)
    (folder / "winter").mkdir()
    names = [f"images-{i:05d}.png" for i in range(count)]
    if nordland is not None and (nordland / "places.csv").is_file():
        for name, (summer, winter) in zip(names, nordland_rows(nordland, count), strict=True):
            shutil.copyfile(summer, folder / "summer" / name)
            shutil.copyfile(winter, folder / "winter" / name)
        return names
    generator = np.random.default_rng(0)
    for name in names:
        image = generator.integers(0, 256, size=(32, 64, 3), dtype=np.uint8)
        cv2.imwrite(str(folder / "summer" / name), image)
        cv2.imwrite(str(folder / "winter" / name), (image // 2 + 40).astype(np.uint8))
    return names


def manifest_text(rows: Iterable[Sequence[object]], head: str = "place_id,summer,winter") -> str:
    return head + "\n" + "".join(",".join(str(cell) for cell in row) + "\n" for row in rows)


def write_manifests(folder: Path, names: Sequence[str]) -> None:
    """places.csv (good) and one defective manifest per variant, all beside the same images."""
    good = [[i, f"summer/{n}", f"winter/{n}"] for i, n in enumerate(names)]

    def edited(row: int, cells: Sequence[object]) -> str:
        return manifest_text(good[:row] + [list(cells)] + good[row + 1 :])

    (folder / "garbage.png").write_bytes(np.random.default_rng(1).integers(0, 256, 2048, dtype=np.uint8).tobytes())
    (folder / "empty.png").write_bytes(b"")
    (folder / "text.png").write_text("not an image\n", encoding="utf-8")
    long_name = "a" * 300 + ".png"
    variants = {
        "places": manifest_text(good),
        "missing_image": edited(3, [3, "summer/nope.png", "winter/nope.png"]),
        "garbage_image": edited(3, [3, "garbage.png", "garbage.png"]),
        "empty_image": edited(3, [3, "empty.png", "empty.png"]),
        "text_image": edited(3, [3, "text.png", "text.png"]),
        "dir_image": edited(3, [3, "summer", "winter"]),
        "long_name": edited(3, [3, long_name, long_name]),
        "huge_id": edited(3, [10**23, good[3][1], good[3][2]]),
        "negative_id": edited(3, [-1, good[3][1], good[3][2]]),
        "float_id": edited(3, [1.5, good[3][1], good[3][2]]),
        "text_id": edited(3, ["x", good[3][1], good[3][2]]),
        "duplicate_id": edited(3, [2, good[3][1], good[3][2]]),
        "empty_cell": edited(3, [3, "", ""]),
        "short_row": edited(3, [3]),
        "header_only": manifest_text([]),
        "wrong_columns": manifest_text(good, head="id,a,b"),
        "no_winter": manifest_text([r[:2] for r in good], head="place_id,summer"),
        "repeated_column": manifest_text(good, head="place_id,summer,summer"),
        "nul_byte": edited(3, [3, "sum\0mer.png", "win\0ter.png"]),
    }
    for name, text in variants.items():
        (folder / f"{name}.csv").write_text(text, encoding="utf-8")
    (folder / "empty.csv").write_bytes(b"")
    (folder / "latin1.csv").write_bytes(manifest_text(good).replace("place_id", "pläce").encode("latin-1"))
    (folder / "binary.csv").write_bytes(np.random.default_rng(2).integers(0, 256, 512, dtype=np.uint8).tobytes())


class _RunsCode:
    """Pickles as a call that ends the process with status 0: a ground truth that runs code reads as ``accepted``."""

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        return (exec, ("__import__('os')._exit(0)",))


def _objects(items: Sequence[Any]) -> np.ndarray:
    array = np.empty(len(items), dtype=object)
    array[:] = list(items)
    return array


class _Reduced:
    """An object whose pickle is exactly ``reduced``: (callable, args[, state])."""

    def __init__(self, *reduced: Any) -> None:
        self.reduced = reduced

    def __reduce__(self) -> Any:
        return self.reduced


def _object_npy(body: bytes, shape: tuple[int, ...]) -> bytes:
    """A .npy file of an object array whose pickle is ``body`` (a header numpy writes, then the opcodes)."""
    handle = io.BytesIO()
    np.lib.format.write_array_header_1_0(handle, {"descr": "|O", "fortran_order": False, "shape": shape})
    return handle.getvalue() + body


def crafted_ground_truths(n: int) -> dict[str, bytes]:
    """Pickles built only from numpy's own array-rebuilding globals (issue 45): through numpy's loader they read
    raw bytes as object pointers (SIGSEGV), allocate a billion elements over 8 bytes, or nest 200,000 deep."""
    rebuild = np._core.multiarray._reconstruct

    def forged(shape: tuple[int, ...], dtype: Any, data: Any) -> _Reduced:
        return _Reduced(rebuild, (np.ndarray, (0,), b"b"), (1, shape, dtype, False, data))

    def file_of(first: Any) -> bytes:
        return _object_npy(pickle.dumps(_objects([first, *[[q] for q in range(1, n)]]), protocol=3), (n,))

    flagged = _Reduced(np.dtype, ("i8", False, True), (3, "<", None, None, None, -1, -1, 1))
    return {
        "forged-object-bytes": file_of(forged((2,), np.dtype(object), b"\x41" * 16)),
        "forged-dtype-flags": file_of(forged((2,), flagged, b"\x41" * 16)),
        "huge-over-8-bytes": file_of(forged((10**9,), np.dtype("i8"), b"\x01" * 8)),
        "long-string": file_of("x" * 20_000_000),
        "deep-nesting": _object_npy(b"\x80\x03" + b"]" * 200_000 + b"a" * 199_999 + b".", (n,)),
    }


def ground_truth_variants(n: int) -> dict[str, tuple[str, Any]]:
    """Defective ground truths of an n-frame (summer, winter) pair: name -> (file name, array or CSV text)."""
    eye = np.eye(n, dtype=np.int64)
    lists = [[q] for q in range(n)]
    rows = np.empty((n, 2), dtype=object)
    rows[:, 0] = list(range(n))
    rows[:, 1] = [[q] for q in range(n)]
    pairs = "query,reference\n" + "".join(f"{q},{q}\n" for q in range(n))
    npy = "summer_winter_GT.npy"
    csv = "summer_winter_GT.csv"
    return {
        "runs-code": (npy, _objects([_RunsCode(), *lists[1:]])),
        "nan": (npy, np.where(eye > 0, 1.0, np.nan)),
        "minus-one": (npy, eye - 2 * (1 - eye)),
        "soft": (npy, eye * 0.9 + 0.1),
        "strings": (npy, eye.astype(str)),
        "complex": (npy, eye.astype(complex)),
        "datetime": (npy, np.zeros((n, n), dtype="datetime64[s]")),
        "list-float": (npy, _objects([[0.9], *lists[1:]])),
        "list-bool": (npy, _objects([[True], *lists[1:]])),
        "list-outside": (npy, _objects([[n], *lists[1:]])),
        "rows-bool-query": (npy, np.concatenate([np.array([[True, [0]]], dtype=object), rows[1:]])),
        "rows-repeated-query": (npy, np.concatenate([rows[:1], rows[:-1]])),
        "square-shifted": (npy, np.roll(eye, 1, axis=0)),
        "wrong-shape": (npy, np.eye(n + 3)),
        "no-match": (npy, np.zeros((n, n))),
        "npz": (npy, {"gt": eye}),
        "truncated": (npy, b"\x93NUMPY\x01\x00"),
        "csv-underscore": (csv, pairs.replace("1,1\n", "1,1_0\n")),
        "csv-arabic": (csv, pairs.replace("1,1\n", "1,\u0661\n")),
        "csv-float": (csv, pairs.replace("1,1\n", "1,1.0\n")),
        "csv-columns": (csv, pairs.replace("query,reference", "q,r")),
        "disagree": ("both", (eye, pairs.replace("1,1\n", "1,2\n"))),
        **{name: (npy, content) for name, content in crafted_ground_truths(n).items()},
    }


def write_offset_routes(fx: Path, images: Path, n: int) -> None:
    """Traversals of different lengths: ``gt_offset`` (winter = summer's places 3..n-1, a LENS-style
    ``winter_summer_GT.npy`` says so) and ``gt_unaligned`` (the same frames and no ground truth)."""
    for name in ("gt_offset", "gt_unaligned"):
        (fx / name).mkdir()
        (fx / name / "summer").symlink_to(images / "summer", target_is_directory=True)
        shutil.copytree(images / "winter", fx / name / "winter")
        for index, path in enumerate(sorted((fx / name / "winter").iterdir())):
            if index < 3:
                path.unlink()
    truth = np.zeros((n, n - 3), dtype=np.int64)
    truth[np.arange(3, n), np.arange(n - 3)] = 1
    np.save(fx / "gt_offset" / "winter_summer_GT.npy", truth)


#: Tampered copies of a calibrated operating point (point.json): name -> the JSON text's edit.
POINT_EDITS: dict[str, Callable[[str], str]] = {
    "threshold-neg": lambda text: re.sub(r'"threshold": [^,]+', '"threshold": -1', text),
    "threshold-zero": lambda text: re.sub(r'"threshold": [^,]+', '"threshold": 0', text),
    "threshold-nan": lambda text: re.sub(r'"threshold": [^,]+', '"threshold": NaN', text),
    "threshold-text": lambda text: re.sub(r'"threshold": [^,]+', '"threshold": "0.5"', text),
    "precision-five": lambda text: re.sub(r'"precision": [^,]+', '"precision": 5', text),
    "deep": lambda text: "[" * 5000 + "]" * 5000,
    "digits": lambda text: re.sub(r'"n_queries": [^,]+', '"n_queries": ' + "9" * 5001, text),
}


def write_tampered_points(fx: Path) -> None:
    point = fx / "point.json"
    if point.is_file():
        for name, edit in POINT_EDITS.items():
            (fx / f"point_{name}.json").write_text(edit(point.read_text(encoding="utf-8")), encoding="utf-8")


def write_escaping_deploys(fx: Path) -> None:
    """Copies of the deploy folder whose export.json (or Loihi network.json) names a file outside it (issue 31);
    ``evil.onnx`` beside them holds the same bytes as the good graph, so only the path check can refuse it."""
    if not (fx / "deploy" / "export.json").is_file():
        return
    shutil.copyfile(fx / "deploy" / "model.onnx", fx / "evil.onnx")
    paths = {
        "parent": "../evil.onnx",
        "dotdot": "deploy/../evil.onnx",
        "absolute": str(fx / "evil.onnx"),
        "symlink": "model.onnx",
    }
    for name, path in paths.items():
        folder = fx / f"deploy_{name}"
        shutil.copytree(fx / "deploy", folder)
        data = json.loads((folder / "export.json").read_text(encoding="utf-8"))
        data["files"]["onnx"][0]["path"] = path
        (folder / "export.json").write_text(json.dumps(data), encoding="utf-8")
        if name == "symlink":
            (folder / "model.onnx").unlink()
            (folder / "model.onnx").symlink_to(fx / "evil.onnx")


def write_resized_streams(fx: Path, images: Path) -> None:
    """``frames_cropped`` (a row and a column short), ``frames_rescaled`` (twice the size), ``frames_one-pixel``
    (1x1) and ``frames_flat`` (uniform grey, the right size) of the winter frames."""
    cv2 = importlib.import_module("cv2")
    for name, change in (
        ("cropped", lambda im: im[:-1, :-1]),
        ("rescaled", lambda im: cv2.resize(im, None, fx=2, fy=2)),
        ("one-pixel", lambda im: im[:1, :1]),
        ("flat", lambda im: np.full_like(im, 128)),
    ):
        (fx / f"frames_{name}").mkdir()
        for path in sorted((images / "winter").iterdir())[:3]:
            cv2.imwrite(str(fx / f"frames_{name}" / path.name), change(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)))


def huge_png(path: Path, side: int) -> None:
    """A real ``side x side`` all-black greyscale PNG, written row by row (a few hundred kB; side**2 bytes decoded)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    packer, row = zlib.compressobj(9), bytes(side + 1)  # filter byte 0, then the row
    idat = b"".join(packer.compress(row) for _ in range(side)) + packer.flush()
    ihdr = struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def write_bag(path: Path, topics: Mapping[str, Sequence[np.ndarray]]) -> None:
    """A ROS 2 bag of mono8 sensor_msgs/Image messages, one topic per entry of ``topics`` (rosbags' writer)."""
    rosbag2 = importlib.import_module("rosbags.rosbag2")
    typesys = importlib.import_module("rosbags.typesys")
    store = typesys.get_typestore(typesys.Stores.ROS2_HUMBLE)
    image, header = store.types["sensor_msgs/msg/Image"], store.types["std_msgs/msg/Header"]
    stamp = store.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    with rosbag2.Writer(path, version=9) as writer:
        for topic, frames in topics.items():
            connection = writer.add_connection(topic, "sensor_msgs/msg/Image", typestore=store)
            for index, grey in enumerate(frames):
                msg = image(
                    header=header(stamp=stamp, frame_id="cam"),
                    height=grey.shape[0],
                    width=grey.shape[1],
                    encoding="mono8",
                    is_bigendian=0,
                    step=grey.shape[1],
                    data=grey.ravel(),
                )
                writer.write(connection, index + 1, store.serialize_cdr(msg, "sensor_msgs/msg/Image"))


def count_events(frames: np.ndarray, window_us: int) -> np.ndarray:
    """A structured x, y, t, p event array whose ``window_us`` time bins count back to ``frames`` (N, H, W)."""
    index, y, x = np.nonzero(frames)
    repeats = frames[index, y, x].astype(np.int64)
    events = np.zeros(int(repeats.sum()), [("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")])
    events["x"], events["y"], events["t"] = (
        np.repeat(x, repeats),
        np.repeat(y, repeats),
        np.repeat(index, repeats) * window_us,
    )
    events["p"] = 1
    return events


def write_experiment_folders(fx: Path, images: Path) -> None:
    """Folder data sets of 24 frames per traversal (``experiment --quick`` reads places 0..23; the 12 images
    repeated): ``exp_aligned`` (index-aligned, no ground truth), ``exp_shifted`` (a CSV ground truth matching
    winter frame j to summer place j + 3) and ``exp_unequal`` (winter 21 frames, no ground truth)."""
    for name, n_winter in (("exp_aligned", 24), ("exp_shifted", 24), ("exp_unequal", 21)):
        for traversal, count in (("summer", 24), ("winter", n_winter)):
            files = sorted((images / traversal).iterdir())
            (fx / name / traversal).mkdir(parents=True)
            for index in range(count):
                shutil.copyfile(files[index % len(files)], fx / name / traversal / f"{index:03d}.png")
    pairs = "".join(f"{q},{(q + 3) % 24}\n" for q in range(24))
    (fx / "exp_shifted" / "summer_winter_GT.csv").write_text("query,reference\n" + pairs, encoding="utf-8")


def write_stream_inputs(fx: Path, images: Path) -> None:
    """Bags, event recordings, a cut video and a 20000 x 20000 PNG for the stream cases (issue 31)."""
    cv2 = importlib.import_module("cv2")
    winter = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((images / "winter").iterdir())[:6]]
    (fx / "frames_huge").mkdir()
    huge_png(fx / "frames_huge" / "f0.png", 20000)
    write_bag(fx / "bag_one", {"/camera": winter})
    write_bag(fx / "bag_two", {"/left": winter, "/right": winter})
    write_bag(fx / "bag_big", {"/camera": [np.zeros((8000, 8000), np.uint8)]})  # 64 MB raw: 128 MB to read
    (fx / "damaged.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(64))
    counts = np.stack(winter) // 16  # 0..15 events per pixel and frame
    counts[:, 0, 0] = np.maximum(counts[:, 0, 0], 1)
    np.save(fx / "events.npy", count_events(counts, 1000))
    wide = count_events(np.ones((2, winter[0].shape[0] + 5, winter[0].shape[1] + 5), np.uint8), 1000)
    np.save(fx / "events_wide.npy", wide)
    np.save(fx / "events_pickle.npy", np.array([{"x": 1}], dtype=object), allow_pickle=True)
    (fx / "events_empty.txt").write_text("# t x y p\n")
    clip = fx / "cut.avi"
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 10, winter[0].shape[::-1], isColor=True)
    for grey in winter * 3:
        writer.write(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR))
    writer.release()
    clip.write_bytes(clip.read_bytes()[: clip.stat().st_size * 2 // 3])


def write_ground_truths(fx: Path, images: Path, n: int) -> None:
    """One folder data set per defective ground truth: summer/ and winter/ linked to ``images``, plus the file."""
    for name, (file_name, content) in ground_truth_variants(n).items():
        folder = fx / f"gt_{name}"
        folder.mkdir()
        for traversal in ("summer", "winter"):
            (folder / traversal).symlink_to(images / traversal, target_is_directory=True)
        if file_name == "both":
            np.save(folder / "summer_winter_GT.npy", content[0])
            (folder / "summer_winter_GT.csv").write_text(content[1], encoding="utf-8")
        elif isinstance(content, str):
            (folder / file_name).write_text(content, encoding="utf-8")
        elif isinstance(content, bytes):
            (folder / file_name).write_bytes(content)
        elif isinstance(content, dict):
            with open(folder / file_name, "wb") as handle:
                np.savez(handle, **content)
        else:
            np.save(folder / file_name, content, allow_pickle=True)


def write_subsets(fx: Path) -> None:
    subsets = {
        "ok": "place_id\n0\n1\n2\n3\n4\n",
        "empty": "",
        "header_only": "place_id\n",
        "wrong_column": "id\n0\n1\n",
        "duplicate": "place_id\n1\n1\n",
        "absent": "place_id\n50\n51\n",
        "text": "place_id\nx\n",
        "huge": f"place_id\n{10**23}\n",
    }
    for name, text in subsets.items():
        (fx / f"subset_{name}.csv").write_text(text, encoding="utf-8")


def write_plain_files(fx: Path) -> None:
    (fx / "empty.npz").write_bytes(b"")
    (fx / "notes.txt").write_text("not a model\n", encoding="utf-8")
    (fx / "garbage.npz").write_bytes(np.random.default_rng(3).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    (fx / "folder.npz").mkdir()
    (fx / "emptydir").mkdir()
    (fx / "nord_noplaces").mkdir()
    with zipfile.ZipFile(fx / "emptyzip.npz", "w"):
        pass
    shutil.copyfile(fx / "net.npz", fx / "ñet 网络.npz")


def make_readonly(folder: Path) -> Path:
    """A folder nothing can be created in: mode 555, and immutable (chattr +i) for root, who ignores modes."""
    folder.mkdir()
    folder.chmod(0o555)
    if os.geteuid() == 0:
        done = subprocess.run(["chattr", "+i", str(folder)], capture_output=True, check=False)
        if done.returncode != 0:
            return Path("/sys/kernel")  # root cannot create files here either
    return folder


def release_readonly(folder: Path) -> None:
    if folder.is_dir() and os.geteuid() == 0:
        subprocess.run(["chattr", "-i", str(folder)], capture_output=True, check=False)
    if folder.is_dir():
        folder.chmod(0o755)


#: Fixtures written by the CLI itself: (argv, must succeed).
CLI_FIXTURES: tuple[tuple[tuple[str, ...], bool], ...] = (
    (("train", "--data", "synthetic:10", "--reference", "summer", *TINY, "--quiet", "--out", "net.npz"), True),
    (
        (
            "train",
            "--data",
            "synthetic:10",
            "--reference",
            "summer",
            *TINY,
            "--seed",
            "7",
            "--quiet",
            "--out",
            "other.npz",
        ),
        True,
    ),
    (("quantize", "net.npz", "--bits", "8,2", "--out", "models/", "--quiet"), True),
    (("export", "models/model_8bit_per-neuron_max.npz", "--to", "nir,loihi,onnx", "--out", "deploy/", "--quiet"), True),
    (("verify", "net.npz", "--bits", "8", "--query", "winter", "--report", "rep", "--quiet"), True),
    (
        ("localize", "models/model_8bit_per-neuron_max.npz", "--calibrate", "winter", "--precision", "0.01")
        + ("--operating-point", "point.json", "--quiet"),
        False,
    ),
    (
        (
            "train",
            "--data",
            "synthetic:10",
            "--reference",
            "summer",
            "--timesteps",
            "1",
            "--epochs",
            "0",
            "--neurons",
            "1",
        )
        + ("--quiet", "--out", "edge.npz"),
        False,
    ),
)


def build_fixtures(fx: Path, run: Runner, nordland: Path | None) -> None:
    """Every file the cases name, in ``fx``; SystemExit when a fixture the campaign needs cannot be made."""
    fx.mkdir(parents=True)
    for argv, needed in CLI_FIXTURES:
        raw = run(argv, fx)
        if raw.rc != 0 and not (argv[0] == "verify" and raw.rc == 1):  # a failed check still writes its report
            message = f"fixture {shlex.join(['vprsnn-export', *argv])} failed (rc {raw.rc}):\n{raw.stderr[-2000:]}"
            if needed:
                raise SystemExit(message)
            print(f"warning: {message}", file=sys.stderr)
    write_tampered(fx, fx / "net.npz", "ck", CHECKPOINT_EDITS)
    write_escaping_deploys(fx)
    write_tampered_points(fx)
    write_tampered(fx, fx / "models" / "model_8bit_per-neuron_max.npz", "fp", MODEL_EDITS)
    write_reports(fx)
    names = write_images(fx / "nord", nordland, 12)
    write_manifests(fx / "nord", names)
    shutil.copytree(fx / "nord", fx / "nörd 路径")
    write_subsets(fx)
    write_plain_files(fx)
    only_images = fx / "nord_frames"
    for traversal in ("summer", "winter"):
        shutil.copytree(fx / "nord" / traversal, only_images / traversal)
    write_ground_truths(fx, only_images, len(names))
    write_offset_routes(fx, only_images, len(names))
    write_resized_streams(fx, only_images)
    write_stream_inputs(fx, only_images)
    write_experiment_folders(fx, only_images)
    write_issue45_fixtures(fx, only_images, len(names))


def write_issue45_fixtures(fx: Path, images: Path, n: int) -> None:
    """Issue 45's files: a manifest folder with a ground-truth file beside it, a deploy folder whose ONNX file
    was bit-flipped after export, a report whose PR curves are ragged, an event recording with a clock jump."""
    shutil.copytree(fx / "nord", fx / "nord_gt")
    np.save(fx / "nord_gt" / "summer_winter_GT.npy", np.roll(np.eye(n, dtype=np.int64), 3, axis=0))
    if (fx / "deploy").is_dir():
        shutil.copytree(fx / "deploy", fx / "deploy_flipped")
        onnx_file = fx / "deploy_flipped" / "model.onnx"
        flipped = bytearray(onnx_file.read_bytes())
        flipped[len(flipped) // 2] ^= 0xFF
        onnx_file.write_bytes(bytes(flipped))
    report = fx / "rep" / "report.json"
    if report.is_file():
        data = json.loads(report.read_text())
        for width in data["runs"][0]["bits"]:
            for curve in width["pr_curves"].values():
                curve["precision"] = curve["precision"][:-1]
        (fx / "rep_ragged").mkdir()
        (fx / "rep_ragged" / "report.json").write_text(json.dumps(data))
    events = np.zeros(3, [("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "i1")])
    events["t"] = [0, 1, 10**15]
    np.save(fx / "events_jump.npy", events)
    frames = fx / "adapt_data"
    for traversal in ("summer", "winter"):
        shutil.copytree(images / traversal, frames / traversal)


# ---------------------------------------------------------------------------------------------- cases


def numeric(
    prefix: str,
    base: Sequence[str],
    option: str,
    *,
    ok: Iterable[str] = (),
    skip: Iterable[str] = (),
    values: Mapping[str, str] | None = None,
    **options: Any,
) -> list[Case]:
    """``base OPTION VALUE`` for every value of VALUES (or ``values``); keys in ``ok`` are legal."""
    table = dict(VALUES if values is None else values)
    legal_keys, skipped = set(ok), set(skip)
    cases = []
    for key, value in table.items():
        if key in skipped:
            continue
        make = legal if key in legal_keys else bad
        cases.append(make(f"{prefix}-{option.lstrip('-')}-{key}", *base, option, value, **options))
    return cases


def cli_cases() -> list[Case]:
    """No command, unknown commands and options, missing required arguments, --help."""
    cases = [
        bad("cli-no-command"),
        bad("cli-unknown-command", "nope"),
        bad("cli-unknown-global-option", "--nope"),
        legal("cli-version", "--version"),
        legal("cli-help", "--help"),
    ]
    minimal = {
        "train": TRAIN,
        "evaluate": EVAL,
        "quantize": QUANT,
        "simulate": SIM,
        "export": EXPORT,
        "verify": VERIFY,
        "report": ("report", "{fx}/rep", "--out", "r"),
        "experiment": EXPERIMENT,
        "demo": DEMO,
    }
    for command, base in minimal.items():
        cases += [
            legal(f"{command}-help", command, "--help"),
            *([] if command == "demo" else [bad(f"{command}-no-arguments", command)]),
            bad(f"{command}-unknown-option", *base, "--nope"),
            bad(f"{command}-unknown-option-value", *base, "--nope=1"),
            bad(f"{command}-typo-quiet", *base, "--quite"),
            bad(f"{command}-stray-argument", *base, "stray.npz"),
        ]
    cases += [
        bad("train-no-reference", "train", "--data", "synthetic:10", "--out", "t.npz"),
        bad("train-no-out", "train", "--data", "synthetic:10", "--reference", "summer"),
        bad("train-no-data", "train", "--reference", "summer", "--out", "t.npz"),
        bad("evaluate-no-query", "evaluate", CK),
        bad("simulate-no-query", "simulate", M8),
        bad("quantize-no-out", "quantize", CK),
        bad("export-no-out", "export", M8),
        bad("verify-no-report", "verify", CK, "--query", "winter"),
        bad("verify-no-query", "verify", CK, "--report", "v"),
        bad("report-several-no-out", "report", "rep", "rep2", copy=("rep", "rep->rep2")),
        bad("experiment-no-name", "experiment", "--quick"),
        bad("train-subset-and-places", *TRAIN, "--subset", "{fx}/subset_ok.csv", "--places", "0:5"),
        bad("quantize-per-tensor-and-per-neuron", *QUANT, "--per-tensor", "--per-neuron"),
    ]
    return cases


SET_KEYS_BOOL = (
    "network.wta",
    "network.state_isolation",
    "stdp.weight_norm",
    "homeostasis.enabled",
    "preprocess.patch_norm",
)


def range_values(low: float, high: float, low_ok: bool, high_ok: bool, integer: bool) -> dict[str, str]:
    """Bad --set values of a numeric key: NaN, infinities, just outside its range, text, null, a list."""
    below = low - 1 if low_ok else low
    above = high + 1 if high_ok else high
    cast = int if integer else float
    return {
        "NaN": "NaN",
        "nan": "nan",
        "Infinity": "Infinity",
        "below": json.dumps(cast(below)),
        "above": json.dumps(cast(above)),
        "text": "abc",
        "null": "null",
        "list": "[1]",
    }


def config_cases() -> list[Case]:
    """--set with bad values for every config key (config.RANGES), cross-field conflicts, unknown keys."""
    config = importlib.import_module("vprsnn_export.config")
    ranges: Mapping[str, tuple[float, float, bool, bool]] = config.RANGES
    defaults = config.Config()  # every section, the optional ones too (to_dict leaves those out at their defaults)
    cases = []
    for key, limits in ranges.items():
        section, _, name = key.rpartition(".")
        if section and not hasattr(defaults, section):
            continue  # not a section of the network's config (verify.*: VerifyConfig, not a --set key of train)
        default = getattr(getattr(defaults, section), name) if section else getattr(defaults, name)
        integer = isinstance(default, int) and not isinstance(default, bool)
        for label, value in range_values(*limits, integer=integer).items():
            cases.append(bad(f"train-set-{key}-{label}", *TRAIN, "--set", f"{key}={value}"))
    for key in SET_KEYS_BOOL:
        for label, value in {"text": "abc", "two": "2", "one": "1", "null": "null", "quoted": '"true"'}.items():
            cases.append(bad(f"train-set-{key}-{label}", *TRAIN, "--set", f"{key}={value}"))
    for label, value in {"rgb": "rgb", "number": "1", "null": "null", "list": "[1]"}.items():
        cases.append(bad(f"train-set-preprocess.channels-{label}", *TRAIN, "--set", f"preprocess.channels={value}"))
    conflicts = {
        "patch-not-divisor": ["preprocess.patch_size=5"],
        "image-size-vs-inputs": ["preprocess.image_size=30"],
        "inputs-vs-image-size": ["network.n_inputs=100"],
        "theta-min-above-max": ["homeostasis.theta_min=200"],
        "dog-centre-above-surround": ["preprocess.dog_sigma_centre=3"],
    }
    for label, items in conflicts.items():
        sets = [arg for item in items for arg in ("--set", item)]
        cases.append(bad(f"train-set-conflict-{label}", *TRAIN, *sets))
    unknown = {
        "key": "nope=1",
        "section-key": "network.nope=1",
        "section": "network=1",
        "no-equals": "encoder.timesteps",
        "no-key": "=5",
        "too-deep": "network.n_neurons.x=1",
        "empty": "",
        "upper-case": "Encoder.Timesteps=20",
    }
    cases += [bad(f"train-set-unknown-{label}", *TRAIN, "--set", item) for label, item in unknown.items()]
    cases += [
        bad("train-preset-unknown", *TRAIN, "--preset", "nope"),
        bad("issue-train-neurons-equals-neg5", *TRAIN, "--neurons=-5"),
        bad("issue-train-rate-scale-Infinity", *TRAIN, "--set", "encoder.rate_scale=Infinity"),
        bad("experiment-set-text", *EXPERIMENT, "--set", "encoder.timesteps=abc"),
        bad("experiment-set-unknown", *EXPERIMENT, "--set", "nope=1"),
        bad("experiment-set-no-equals", *EXPERIMENT, "--set", "encoder.timesteps"),
        bad("experiment-set-zero-neurons", *EXPERIMENT, "--set", "network.n_neurons=0"),
    ]
    return cases


K_BAD = {
    "zero": "0",
    "neg": "-1",
    "nan": "nan",
    "text": "abc",
    "empty": "",
    "huge": "100000000",
    "above-queries": "11",
    "gap": "1,,x",
    "float": "1.5",
}
K_OK = {"one": "1", "all-queries": "10", "list": "1,3,5"}
SEARCH_BAD = {
    "nan": "nan:nan:nan",
    "inf": "0:inf:1",
    "tiny-step": "0:1:1e-6",
    "reversed": "1:0:1",
    "zero-step": "0:1:0",
    "neg-step": "0:1:-1",
    "text": "abc",
    "empty": "",
    "two-parts": "0:1",
    "four-parts": "0:1:1:1",
}
SEARCH_OK = {"neg-range": "-2:2:0.5", "single": "1:1:1"}


def readout_cases(prefix: str, base: Sequence[str]) -> list[Case]:
    """--k, the velocity options and --match-window of evaluate, simulate (and a share of verify)."""
    cases = numeric(prefix, base, "--k", values={**K_BAD, **K_OK}, ok=K_OK)
    velocities = {**VALUES, "minus-inf": "-inf", "half": "0.5"}
    cases += numeric(prefix, [*base, "--k", "3"], "--velocity", ok={"neg", "half"}, values=velocities)
    # at k = 1 there is no velocity to estimate (issue 45: refused, i45 cases): the grid is tried at k = 3
    cases += numeric(prefix, [*base, "--k", "3"], "--velocity-search", values={**SEARCH_BAD, **SEARCH_OK}, ok=SEARCH_OK)
    cases += numeric(prefix, base, "--velocity-span", values={**VALUES, "one": "1"}, ok={"one"})
    cases += numeric(
        prefix, base, "--match-window", ok={"zero", "nine"}, values={**VALUES, "above": "1000001", "nine": "9"}
    )
    cases += numeric(prefix, [*base, "--velocity-search", "0:2:0.5"], "--velocity-estimate", values={"x": "x"})
    cases += [
        bad(f"{prefix}-rule-max", *base, "--rule", "max"),
        bad(f"{prefix}-old-tolerance", *base, "--tolerance=-3"),
        bad(f"{prefix}-old-tolerance-1", *base, "--tolerance", "1"),
        bad(f"{prefix}-k3-velocity-nan", *base, "--k", "3", "--velocity", "nan"),
        legal(
            f"{prefix}-velocity-window",
            *base,
            "--k",
            "3",
            "--velocity-search",
            "-1:1:0.5",
            "--velocity-estimate",
            "window",
        ),
    ]
    return cases


def common_runtime_cases(prefix: str, base: Sequence[str], threads: bool = True) -> list[Case]:
    cases = (
        numeric(prefix, base, "--threads", values={**VALUES, "one": "1", "two": "2"}, ok={"one", "two"})
        if threads
        else []
    )
    cases += [
        bad(f"{prefix}-device-gpu", *base, "--device", "gpu"),
        bad(f"{prefix}-device-empty", *base, "--device", ""),
    ]
    cuda = importlib.import_module("torch").cuda.is_available()
    cases.append(
        (legal if cuda else bad)(f"{prefix}-device-cuda", *base, "--device", "cuda", note="no CUDA GPU on this machine")
    )
    return cases


PLACES_BAD = {
    "zero-count": "0:0",
    "neg-start": "-1:5",
    "huge-count": "0:99999999999",
    "text": "abc",
    "zero-stride": "0:5:0",
    "neg-stride": "0:5:-1",
    "nan": "nan:5",
    "empty": "",
    "absent": "8:5",
    "one-part": "0",
    "four-parts": "0:1:2:3",
    "float": "1.5:3",
}


def data_cases(prefix: str, base: Sequence[str]) -> list[Case]:
    """--data and --places values, for the commands that load data."""
    data_bad = {
        "synthetic-0": "synthetic:0",
        "synthetic-neg": "synthetic:-1",
        "synthetic-text": "synthetic:abc",
        "synthetic-huge": "synthetic:100000000000",
        "synthetic-empty": "synthetic:",
        "synthetic-exp": "synthetic:1e3",
        "empty": "",
        "missing": "/nope/places.csv",
        "nordland-missing": "../shared/data/nordland_missing",
        "folder-no-manifest": "{fx}/nord_noplaces",
        "text-file": "{fx}/notes.txt",
        "npz-file": CK,
        "dev-null": "/dev/null",
    }
    cases = numeric(prefix, base, "--data", values=data_bad)
    cases += numeric(prefix, base, "--places", values=PLACES_BAD)
    return cases


def train_cases() -> list[Case]:
    cases = numeric("train", TRAIN, "--epochs", ok={"zero"})
    cases += numeric("train", TRAIN, "--timesteps", values={**VALUES, "one": "1"}, ok={"one"})
    cases += numeric("train", TRAIN, "--neurons", values={**VALUES, "one": "1"}, ok={"one"})
    cases += numeric("train", TRAIN, "--module-size", values={**VALUES, "one": "1"}, ok={"zero", "one"})
    cases += numeric(
        "train", TRAIN, "--seed", ok={"zero"}, values={**VALUES, "max": str(2**63 - 1), "above-max": str(2**63)}
    )
    cases += common_runtime_cases("train", TRAIN)
    cases += data_cases("train", TRAIN)
    references = {
        "empty": "",
        "comma": ",",
        "unknown": "autumn",
        "place-id": "place_id",
        "one-unknown": "summer,autumn",
    }
    cases += numeric("train", TRAIN, "--reference", values=references)
    # train --adapt-from (issue 34): the ranges, an incomplete or impossible adaptation
    adapt = (*TRAIN, "--adapt-from", "winter", "--adapt", "gain")
    cases += numeric("train-adapt", adapt, "--adapt-places", values={**PLACES_BAD, "ranges": "0:5,7:3"}, ok={"ranges"})
    cases += [
        legal("train-adapt", *adapt),
        legal("train-adapt-truth", *adapt, "--adapt-pairing", "truth"),
        bad("train-adapt-without-mechanism", *TRAIN, "--adapt-from", "winter"),
        bad("train-adapt-without-traversal", *TRAIN, "--adapt", "gain"),
        bad("train-adapt-from-reference", *TRAIN, "--adapt-from", "summer", "--adapt", "gain"),
        bad("train-adapt-from-unknown", *TRAIN, "--adapt-from", "autumn", "--adapt", "gain"),
        bad("train-adapt-unknown-mechanism", *TRAIN, "--adapt-from", "winter", "--adapt", "whiten"),
        bad("train-adapt-places-alone", *TRAIN, "--adapt-places", "0:5"),
        bad("train-adapt-one-place", *adapt, "--adapt-places", "0:1"),
    ]
    # --cluster (issue 31): a port out of range, a head nothing answers on (refused at once, not after 35 s)
    clusters = {
        "port-99999": "ray://127.0.0.1:99999",
        "port-0": "ray://127.0.0.1:0",
        "unreachable": "ray://127.0.0.1:1",
    }
    cases += [bad(f"train-cluster-{name}", *TRAIN, "--cluster", value) for name, value in clusters.items()]
    return cases


def memory_cases() -> list[Case]:
    """Runs whose predicted memory exceeds the limit (src/vprsnn_export/resources.py) and the limit's option."""
    limit = ("--memory-limit", "8G")
    big = ("train", "--data", "synthetic:300", "--reference", "summer", "--epochs", "1", "--neurons", "16")
    cases = [
        bad("memory-train-million-neurons", *TRAIN, "--neurons", "1000000", *limit),
        bad("memory-train-T100000", *big, "--timesteps", "100000", "--out", "t.npz", *limit),
        bad("memory-train-modules", *TRAIN, "--neurons", "100000", "--module-size", "1", *limit),
        bad("memory-evaluate-1K", *EVAL, "--memory-limit", "1K"),
        bad("memory-simulate-1K", *SIM, "--memory-limit", "1K"),
        bad("memory-verify-1K", *VERIFY, "--memory-limit", "1K"),
        legal("memory-train-64G", *TRAIN, "--memory-limit", "64G"),
        legal("memory-train-fraction", *TRAIN, "--memory-limit", "1.5G"),
    ]
    cases += numeric("train", TRAIN, "--memory-limit", values={**VALUES, "superscript": "²G", "unit-only": "G"})
    return cases


def evaluate_cases() -> list[Case]:
    cases = readout_cases("evaluate", EVAL)
    cases += common_runtime_cases("evaluate", EVAL)
    cases += data_cases("evaluate", EVAL)
    cases += numeric("evaluate", EVAL, "--query", values={"empty": "", "unknown": "autumn", "place-id": "place_id"})
    cases += [
        bad("evaluate-k-above-one-place", *EVAL, "--places", "0:1", "--k", "3"),
        # the baselines read the checkpoint's own reference frames (issue 45): queries of other places are scored
        legal("evaluate-baseline-other-places", *EVAL, "--baseline", "--places", "0:5"),
    ]
    return cases


def simulate_cases() -> list[Case]:
    cases = readout_cases("simulate", SIM)
    cases += common_runtime_cases("simulate", SIM)
    cases += data_cases("simulate", SIM)
    cases += numeric("simulate", SIM, "--query", values={"empty": "", "unknown": "autumn"})
    compare = {
        "missing": "/nope",
        "folder": "{fx}/emptydir",
        "empty": "{fx}/empty.npz",
        "other-checkpoint": OTHER,
        "model": M8,
        "tampered": "{fx}/ck_header-list.npz",
        "dev-null": "/dev/null",
    }
    cases += numeric("simulate", SIM, "--compare", values=compare)
    return cases


BITS_BAD = {
    "zero": "0",
    "one": "1",
    "nine": "9",
    "neg": "-1",
    "nan": "nan",
    "text": "abc",
    "empty": "",
    "huge": "100000000",
    "gap": "8,,x",
    "float": "4.5",
}
BITS_OK = {"two-only": "2", "duplicate": "8,8"}


def quantize_cases() -> list[Case]:
    cases = numeric("quantize", QUANT, "--bits", values={**BITS_BAD, **BITS_OK}, ok=BITS_OK)
    cases += common_runtime_cases("quantize", QUANT)
    cases += data_cases("quantize", QUANT)
    cases += [
        bad("quantize-scale-x", *QUANT, "--scale", "x"),
        bad("quantize-fold-per-tensor", *QUANT, "--fold-thresholds", "--per-tensor"),
        bad("quantize-non-leaky-reuse-float", *QUANT, "--non-leaky", "--reuse-float-calibration"),
        bad("quantize-places-other", *QUANT, "--places", "0:5"),
    ]
    return cases


def export_cases() -> list[Case]:
    from_checkpoint = ("export", CK, "--to", "onnx", "--out", "x")
    check = (*EXPORT, "--check")
    cases = numeric("export", from_checkpoint, "--quantize", values={**BITS_BAD, "two": "2"}, ok={"two"}, skip={"gap"})
    cases += numeric(
        "export", EXPORT, "--nir-inhibition", ok={"zero", "half"}, skip={"huge"}, values={**VALUES, "half": "0.5"}
    )
    cases += numeric(
        "export", check, "--check-samples", ok={"zero", "one"}, values={**VALUES, "one": "1", "issue": "-5"}
    )
    targets = {"empty": "", "unknown": "tflite", "comma": ","}
    lenient = {"nir": "nir", "two": "onnx,nir", "gap": "nir,,", "upper": "NIR,ONNX"}  # empty items, any case: by design
    cases += numeric("export", EXPORT, "--to", values={**targets, **lenient}, ok=lenient)
    cases += common_runtime_cases("export", check)
    cases += numeric("export", [*check, "--query", "winter"], "--places", values=PLACES_BAD)
    cases += [
        bad("export-checkpoint-to-loihi", "export", CK, "--to", "loihi", "--out", "x"),
        bad("export-model-with-quantize", *EXPORT, "--quantize", "4"),
        bad("export-check-query-unknown", *check, "--query", "autumn"),
        bad("export-check-data-missing", *check, "--query", "winter", "--data", "/nope.csv"),
        bad("export-nir-consumer-x", *check, "--nir-consumer", "x"),
        bad("export-places-without-query", *check, "--places", "abc", note="--places is unused without --query"),
        bad("export-query-without-check", *EXPORT, "--query", "autumn", note="--query is unused without --check"),
        bad("export-into-existing-export", "export", M8, "--out", "deploy", copy=("deploy",), note="needs --force"),
        bad(
            "quantize-out-link-to-folder",
            "quantize",
            CK,
            "--bits",
            "8",
            "--out",
            "link",
            links=(("link", "real"),),
            note="a link to a folder: outputs are never links",
        ),  # fmt: skip
    ]
    if importlib.util.find_spec("norse") is None:
        cases.append(
            legal(
                "export-nir-consumer-norse-missing",
                *check,
                "--nir-consumer",
                "norse",
                note="norse absent: since the consumer gate (issue 23) its row says the package is missing, not gated",
            )
        )
    return cases


def verify_cases() -> list[Case]:
    cases = numeric("verify", VERIFY, "--bits", values={**BITS_BAD, **BITS_OK}, ok=BITS_OK)
    cases += numeric("verify", VERIFY, "--k", values={**K_BAD, **K_OK}, ok=K_OK)
    cases += numeric("verify", VERIFY, "--velocity", skip={"neg"})
    cases += numeric("verify", VERIFY, "--velocity-search", values=SEARCH_BAD)
    cases += numeric("verify", VERIFY, "--match-window", ok={"zero"})
    cases += numeric("verify", VERIFY, "--reference-queries", ok={"zero"})
    cases += numeric("verify", VERIFY, "--seeds", values={**VALUES, "one": "1"}, ok={"one"})
    tolerances = {
        "text": "accuracy=abc",
        "unknown": "nope=0.1",
        "no-value": "accuracy",
        "neg": "accuracy=-1",
        "nan": "accuracy=nan",
        "inf": "accuracy=inf",
        "empty": "",
        "gap": "accuracy=0.1,,x",
        "off": "accuracy=off",
        "fractions": "r_at_100p=0.5,auc_pr=0.5",
    }
    cases += numeric("verify", VERIFY, "--tolerance", values=tolerances, ok={"off", "fractions"})
    targets = {"unknown": "tflite", "empty": "", "gap": "nir,,x", "none": "none", "onnx": "onnx"}
    cases += numeric("verify", VERIFY, "--targets", values=targets, ok={"none", "onnx"})
    cases += common_runtime_cases("verify", VERIFY)
    cases += data_cases("verify", VERIFY)
    cases += [
        bad("verify-old-gt-tolerance", *VERIFY, "--gt-tolerance", "1"),
        bad("verify-seeds-two-checkpoints", "verify", CK, OTHER, "--seeds", "2", "--query", "winter", "--report", "v"),
        bad("verify-query-unknown", "verify", CK, "--query", "autumn", "--report", "v"),
        bad("verify-model-not-checkpoint", "verify", M8, "--query", "winter", "--report", "v"),
        bad("verify-scale-x", *VERIFY, "--scale", "x"),
        bad("verify-fold-per-tensor", *VERIFY, "--fold-thresholds", "--per-tensor"),
        bad("verify-non-leaky-reuse-float", *VERIFY, "--non-leaky", "--reuse-float-calibration"),
        bad("verify-per-tensor-and-per-neuron", *VERIFY, "--per-tensor", "--per-neuron"),
    ]
    return cases


def experiment_cases() -> list[Case]:
    cases = numeric("experiment", EXPERIMENT, "--seeds", values={**VALUES, "issue": "-2"})
    names = {"unknown": "nope", "empty": "", "path": "../assignment", "helper": "common", "upper": "ASSIGNMENT"}
    for label, name in names.items():
        cases.append(bad(f"experiment-name-{label}", "experiment", name, "--quick", "--out", "e"))
    data = {
        "missing": "/nope.csv",
        "text-file": "{fx}/notes.txt",
        "synthetic-0": "synthetic:0",
        "folder": "{fx}/emptydir",
    }
    cases += numeric("experiment", EXPERIMENT, "--data", values=data)
    cases += [bad("experiment-device-gpu", *EXPERIMENT, "--device", "gpu")]
    return cases


def demo_cases() -> list[Case]:
    cases = numeric("demo", DEMO, "--seed", ok={"zero"})
    cases += common_runtime_cases("demo", DEMO)
    return cases


def file_argument_cases() -> list[Case]:
    """The model/checkpoint argument of evaluate, quantize, simulate, export and verify: missing, a folder, empty,
    truncated, of the wrong kind."""
    wrong = {
        "missing": "/nope/net.npz",
        "missing-relative": "net.npz",
        "folder": "{fx}/folder.npz",
        "fixture-folder": "{fx}",
        "empty": "{fx}/empty.npz",
        "garbage": "{fx}/garbage.npz",
        "empty-zip": "{fx}/emptyzip.npz",
        "text": "{fx}/notes.txt",
        "csv": NORD,
        "png": "{fx}/nord/summer/images-00000.png",
        "onnx": "{fx}/deploy/model.onnx",
        "nir": "{fx}/deploy/model.nir",
        "dev-null": "/dev/null",
        "empty-name": "",
    }
    commands = {
        "evaluate": lambda path: ("evaluate", path, "--query", "winter"),
        "quantize": lambda path: ("quantize", path, "--bits", "8", "--out", "q"),
        "simulate": lambda path: ("simulate", path, "--query", "winter"),
        "export": lambda path: ("export", path, "--out", "x"),
        "verify": lambda path: ("verify", path, "--bits", "8", "--query", "winter", "--report", "v"),
    }
    cases = []
    for command, argv in commands.items():
        kinds = {**wrong, "model": M8} if command in ("evaluate", "quantize", "verify") else {**wrong}
        if command == "simulate":
            kinds["checkpoint"] = CK
        for label, path in kinds.items():
            cases.append(bad(f"{command}-file-{label}", *argv(path)))
    return cases


def tamper_cases() -> list[Case]:
    """Tampered checkpoints into evaluate, quantize, export and verify; tampered models into simulate and export."""
    checkpoint_commands = {
        "evaluate": lambda path: ("evaluate", path, "--query", "winter"),
        "quantize": lambda path: ("quantize", path, "--bits", "8", "--out", "q"),
        "export": lambda path: ("export", path, "--to", "nir", "--out", "x"),
        "verify": lambda path: ("verify", path, "--bits", "8", "--query", "winter", "--report", "v"),
    }
    model_commands = {
        "simulate": lambda path: ("simulate", path, "--query", "winter"),
        "export": lambda path: ("export", path, "--out", "x"),
    }
    cases = []
    for edit in [*CHECKPOINT_EDITS, *RAW_DEFECTS]:
        for command, argv in checkpoint_commands.items():
            case_id, line = f"{command}-ckpt-{edit}", argv(f"{{fx}}/ck_{edit}.npz")
            cases.append(legal(case_id, *line, note=UNUSED[case_id]) if case_id in UNUSED else bad(case_id, *line))
    for edit in [*MODEL_EDITS, *RAW_DEFECTS]:
        for command, argv in model_commands.items():
            case_id, line = f"{command}-model-{edit}", argv(f"{{fx}}/fp_{edit}.npz")
            cases.append(legal(case_id, *line, note=UNUSED[case_id]) if case_id in UNUSED else bad(case_id, *line))
    return cases


#: Header fields a command never reads are provenance there, not input: it runs (the commands
#: that do read them refuse the same files). A model's source_sha256 may be a label
#: (``vx.deploy(ckpt, "quickstart", ...)``), so a short one is legal.
UNUSED: dict[str, str] = {
    "evaluate-ckpt-traversals-unknown": "evaluate reads the query traversal only; quantize/verify refuse it",
    "export-ckpt-traversals-unknown": "export does not load data; quantize/verify refuse it",
    "export-ckpt-data-source-missing": "export without --check does not load data",
    "export-ckpt-ref-ids-absent": "export does not evaluate; evaluate refuses it",
    "simulate-model-source-sha-short": "a label is a legal source_sha256 (in-memory checkpoints)",
    "export-model-source-sha-short": "a label is a legal source_sha256 (in-memory checkpoints)",
}


def report_cases() -> list[Case]:
    """report on missing, empty and tampered report folders, and bad combinations."""
    edits = [*REPORT_EDITS, "truncated", "empty-file", "not-utf8", "json-is-folder"]
    cases = [bad(f"report-{edit}", "report", f"rp_{edit}", copy=(f"rp_{edit}",)) for edit in edits]
    cases += [
        bad(f"report-combine-{edit}", "report", "rep", f"rp_{edit}", "--out", "c", copy=("rep", f"rp_{edit}"))
        for edit in ("no-float-run", "runs-empty", "list")
    ]
    cases += [
        bad("report-missing", "report", "/nope"),
        bad("report-empty-folder", "report", "{fx}/emptydir"),
        bad("report-npz-file", "report", CK),
        bad("report-text-file", "report", "{fx}/notes.txt"),
        bad("report-same-twice", "report", "rep", "rep", "--out", "c", copy=("rep",)),
        bad("report-same-twice-json", "report", "rep", "rep/report.json", "--out", "c", copy=("rep",)),
        bad("report-empty-name", "report", ""),
    ]
    cases += [
        legal(
            f"report-{edit}", "report", f"rp_{edit}", copy=(f"rp_{edit}",), note="renders with the string on one line"
        )
        for edit in REPORT_LEGAL_EDITS
    ]
    return cases


def manifest_cases() -> list[Case]:
    """Defective place manifests and subset files, into train and evaluate."""
    manifests = [
        "missing_image",
        "garbage_image",
        "empty_image",
        "text_image",
        "dir_image",
        "long_name",
        "huge_id",
        "negative_id",
        "float_id",
        "text_id",
        "duplicate_id",
        "empty_cell",
        "short_row",
        "header_only",
        "wrong_columns",
        "no_winter",
        "repeated_column",
        "empty",
        "latin1",
        "binary",
        "nul_byte",
    ]
    cases = []
    for name in manifests:
        path = f"{{fx}}/nord/{name}.csv"
        cases.append(
            bad(
                f"train-manifest-{name}",
                "train",
                "--data",
                path,
                "--reference",
                "summer,winter",
                *TINY,
                "--out",
                "t.npz",
            )
        )
        cases.append(bad(f"evaluate-manifest-{name}", *EVAL, "--data", path))
    subsets = ["empty", "header_only", "wrong_column", "duplicate", "absent", "text", "huge"]
    subset_paths = {name: f"{{fx}}/subset_{name}.csv" for name in subsets}
    subset_paths.update(missing="/nope/subset.csv", folder="{fx}/emptydir")
    for name, path in subset_paths.items():
        cases.append(
            bad(
                f"train-subset-{name}",
                "train",
                "--data",
                NORD,
                "--subset",
                path,
                "--reference",
                "summer",
                *TINY,
                "--out",
                "t.npz",
            )
        )
        cases.append(bad(f"evaluate-subset-{name}", *EVAL, "--subset", path))
    return cases


#: Bad output folders for the commands that write a folder (quantize, export, verify, report, experiment, demo).
FOLDER_OUTPUTS: dict[str, tuple[str, dict[str, Any]]] = {
    "empty": ("", {}),
    "readonly": ("{ro}", {}),
    "readonly-sub": ("{ro}/sub", {}),
    "proc": ("/proc/x", {}),
    "dev-full": ("/dev/full", {}),
    "dev-null": ("/dev/null", {}),
    "file": ("notes.txt", {"copy": ("notes.txt",)}),
    "link-to-file": ("link", {"links": (("link", "{fx}/notes.txt"),)}),
    "dangling-link": ("link", {"links": (("link", "/nope/target"),)}),
    "parent-is-file": ("notes.txt/sub", {"copy": ("notes.txt",)}),
    "long-name": ("a" * 300, {}),
}


def sh(text: str) -> tuple[str, ...]:
    """The argv of a command line written with shell quoting (placeholders such as {fx} kept)."""
    return tuple(shlex.split(text))


FX = "{fx}"
T_TINY = "train --data synthetic:10 --reference summer --timesteps 20 --epochs 1 --neurons 16"

#: Output paths that are the command's own input, or exist already (case id -> command line, fixtures copied).
INPUT_AS_OUTPUT: dict[str, tuple[str, tuple[str, ...]]] = {
    "train-out-is-manifest": (f"{T_TINY} --data nord/places.csv --out nord/places.csv", ("nord",)),
    "train-out-is-manifest-force": (f"{T_TINY} --data nord/places.csv --out nord/places.csv --force", ("nord",)),
    "train-out-is-subset-force": (f"{T_TINY} --subset subset_ok.csv --out subset_ok.csv --force", ("subset_ok.csv",)),
    "quantize-out-is-input": ("quantize net.npz --bits 8 --out net.npz", ("net.npz",)),
    "quantize-out-exists-no-force": (f"quantize {CK} --bits 8 --out models", ("models",)),
    "export-out-is-input": (
        "export models/model_8bit_per-neuron_max.npz --out models/model_8bit_per-neuron_max.npz",
        ("models",),
    ),
    "verify-report-is-input": ("verify net.npz --bits 8 --query winter --report net.npz", ("net.npz",)),
    "report-out-is-input": ("report rep --out rep/report.json", ("rep",)),
    "evaluate-predictions-is-manifest": (
        f"evaluate {CK} --query winter --data nord/places.csv --predictions nord/places.csv",
        ("nord",),
    ),
    "evaluate-predictions-is-subset": (
        f"evaluate {CK} --query winter --subset subset_ok.csv --predictions subset_ok.csv",
        ("subset_ok.csv",),
    ),
    "localize-calibration-is-model": ("localize net.npz --calibrate winter --operating-point net.npz", ("net.npz",)),
    "localize-calibration-is-manifest": (
        f"localize {CK} --calibrate winter --data nord/places.csv --operating-point nord/places.csv",
        ("nord",),
    ),
    "localize-calibration-is-ground-truth": (
        f"localize {CK} --calibrate winter --data gt_offset --operating-point gt_offset/winter_summer_GT.npy",
        ("gt_offset",),
    ),
    "localize-calibration-accepts-nothing": (
        f"localize {EDGE} --calibrate winter --precision 1 --operating-point p.json",
        (),
    ),
}


def output_cases() -> list[Case]:
    """--out (--report) targets that cannot or must not be written, in all seven writing commands."""
    train_out: dict[str, tuple[str, dict[str, Any]]] = {
        "empty": ("", {}),
        "readonly": ("{ro}/t.npz", {}),
        "proc": ("/proc/x.npz", {}),
        "existing-folder": (".", {}),
        "tmp": ("/tmp", {}),
        "dev-full": ("/dev/full", {}),
        "dev-null": ("/dev/null", {}),
        "link-to-file": ("link.npz", {"links": (("link.npz", "{fx}/notes.txt"),)}),
        "dangling-link": ("link.npz", {"links": (("link.npz", "/nope/target.npz"),)}),
        "exists-no-force": ("net.npz", {"copy": ("net.npz",)}),
        "parent-is-file": ("net.npz/x.npz", {"copy": ("net.npz",)}),
        "long-name": ("a" * 300 + ".npz", {}),
    }
    cases = [bad(f"train-out-{label}", *sh(T_TINY), "--out", out, **extra) for label, (out, extra) in train_out.items()]
    writers = {
        "quantize": f"quantize {CK} --bits 8 --out",
        "export": f"export {M8} --out",
        "verify": f"verify {CK} --bits 8 --query winter --report",
        "report": f"report {FX}/rep --out",
        "experiment": "experiment assignment --quick --out",
        "demo": "demo --quick --out",
    }
    for command, text in writers.items():
        cases += [
            bad(f"{command}-out-{label}", *sh(text), out, **extra) for label, (out, extra) in FOLDER_OUTPUTS.items()
        ]
    cases += [bad(name, *sh(text), copy=copy) for name, (text, copy) in INPUT_AS_OUTPUT.items()]
    return cases


#: Legal extremes that must run (besides the legal values of the option lists above): id -> command line.
LEGAL_LINES: dict[str, str] = {
    "localize-frames-reference-size": f"localize {M8} --frames {{fx}}/nord/winter --threshold 0.5",
    "localize-frames-bag": f"localize {M8} --frames {{fx}}/bag_one --threshold 0.5",
    "localize-frames-events": f"localize {M8} --frames {{fx}}/events.npy --event-window-us 1000 --threshold 0.5",
    "evaluate-gt-offset": "evaluate {fx}/net.npz --data {fx}/gt_offset --query winter --k 1,3",
    "simulate-gt-offset": f"simulate {M8} --data {{fx}}/gt_offset --query winter",
    "train-T1-one-neuron-0-epochs": "train --data synthetic:10 --reference summer --timesteps 1 --neurons 1 --epochs 0 --out e.npz",
    "train-one-place": "train --data synthetic:1 --reference summer --timesteps 20 --epochs 1 --neurons 16 --out t.npz",
    "train-places-one": f"{T_TINY} --places 0:1 --out t.npz",
    "train-places-stride": f"{T_TINY} --places 3:2:2 --out t.npz",
    "train-modules-uneven": f"{T_TINY} --module-size 4 --out t.npz",
    "train-module-larger-than-route": f"{T_TINY} --module-size 50 --out t.npz",
    "train-synthetic-default": f"{T_TINY} --data synthetic --out t.npz",
    "train-two-references": f"{T_TINY} --reference summer,winter --out t.npz",
    "train-unicode-out": f"{T_TINY} --out 'Ünïcödé ñet 网络.npz'",
    "train-nested-out": f"{T_TINY} --out a/b/c/t.npz",
    "train-force": f"{T_TINY} --out net.npz --force",
    "train-manifest": f"{T_TINY} --data {NORD} --out t.npz",
    "train-manifest-folder": f"{T_TINY} --data {FX}/nord --reference winter --out t.npz",
    "train-manifest-unicode": f"{T_TINY} --data '{FX}/nörd 路径/places.csv' --out ü.npz",
    "train-subset": f"{T_TINY} --data {NORD} --subset {FX}/subset_ok.csv --out t.npz",
    "train-preset-dog": f"{T_TINY} --preset dog --out t.npz",
    "train-ablations": f"{T_TINY} --no-wta --no-homeostasis --no-patch-norm --no-weight-norm --no-state-isolation --out t.npz",
    "train-set-bounds": f"{T_TINY} --set homeostasis.eta=0 --set stdp.a_plus=0 --set assignment.gamma=1 --set network.beta=1 --out t.npz",
    "train-small-image": (
        f"{T_TINY} --preset paper --set preprocess.image_size=7 --set preprocess.patch_size=7 "
        "--set network.n_inputs=49 --out t.npz"
    ),
    "train-small-image-dog": (
        f"{T_TINY} --set preprocess.image_size=7 --set preprocess.patch_size=7 --set network.n_inputs=98 --out t.npz"
    ),
    "train-batch-one": f"{T_TINY} --set train.batch_size=1 --out t.npz",
    "train-quiet": f"{T_TINY} --quiet --out t.npz",
    "evaluate-edge-network": f"evaluate {EDGE} --query winter",
    "evaluate-unicode-file": f"evaluate '{FX}/ñet 网络.npz' --query winter",
    "evaluate-one-place": f"evaluate {CK} --query winter --places 0:1",
    "evaluate-json": f"evaluate {CK} --query winter --json --k 1,3",
    "evaluate-baseline": f"evaluate {CK} --query winter --baseline",
    "evaluate-spillover": f"evaluate {CK} --query winter --no-state-isolation",
    "evaluate-rule-sum": f"evaluate {CK} --query winter --k 3 --rule sum",
    "evaluate-query-reference": f"evaluate {CK} --query summer",
    "evaluate-manifest": f"evaluate {CK} --query winter --data {NORD} --places 0:10",
    "evaluate-subset": f"evaluate {CK} --query winter --subset {FX}/subset_ok.csv",
    "evaluate-device-cpu": f"evaluate {CK} --query winter --device cpu",
    "quantize-edge-network": f"quantize {EDGE} --bits 2 --out q",
    "quantize-all-options": f"quantize {CK} --bits 8 --out q --per-tensor --scale mse --json",
    "quantize-fold": f"quantize {CK} --bits 8 --out q --fold-thresholds",
    "quantize-reuse-float": f"quantize {CK} --bits 8 --out q --reuse-float-calibration",
    "quantize-non-leaky": f"quantize {CK} --bits 8 --out q --non-leaky",
    "quantize-out-existing-folder": f"quantize {CK} --bits 8 --out .",
    "quantize-out-unicode": f"quantize {CK} --bits 2 --out 'módèls 模型'",
    "quantize-force": f"quantize {CK} --bits 8 --out models --force",
    "simulate-2bit": f"simulate {M2} --query winter",
    "simulate-compare": f"simulate {M8} --query winter --compare {CK}",
    "simulate-json": f"simulate {M8} --query winter --json --k 1,3,5",
    "simulate-one-place": f"simulate {M8} --query winter --places 0:1",
    "export-checkpoint-nir": f"export {CK} --to nir --out x",
    "export-2bit-onnx": f"export {M2} --to onnx --out x",
    "export-check-query": f"export {M8} --out x --check --query winter --json",
    "export-no-wta-node": f"export {M8} --out x --nir-no-wta-node --to nir",
    "export-out-unicode": f"export {M8} --out 'düpløy 导出'",
    "export-into-existing-export": f"export {M8} --out deploy --force",
    "export-edge-network": f"export {EDGE} --quantize 2 --out x",
    "verify-edge-network": f"verify {EDGE} --bits 2 --query winter --report v",
    "verify-two-checkpoints": f"verify {CK} {OTHER} --bits 8 --query winter --report v",
    "verify-same-checkpoint-twice": f"verify {CK} {CK} --bits 8 --query winter --report v",
    "verify-quick-options": f"verify {CK} --bits 8 --query winter --report v --k 1 --reference-queries 0 --targets none --per-tensor --scale mse --json",
    "verify-reuse-float": f"verify {CK} --bits 8 --query winter --report v --reuse-float-calibration",
    "verify-fold": f"verify {CK} --bits 8 --query winter --report v --fold-thresholds --scale mse",
    "verify-non-leaky": f"verify {CK} --bits 8 --query winter --report v --non-leaky",
    "verify-places": f"verify {CK} --bits 8 --query winter --report v --places 0:5",
    "verify-report-unicode": f"verify {CK} --bits 2 --query winter --report 'rëport 报告'",
    "report-in-place": "report rep",
    "report-json-file": "report rep/report.json --out r2",
    "report-combine-copies": "report rep rep2 --out c",
    "report-quiet-unicode": f"report {FX}/rep --out 'rëp 报告' --quiet",
    "experiment-list": "experiment list",
    "experiment-assignment-quick": "experiment assignment --quick --out e",
    "experiment-seeds-one": "experiment assignment --quick --out e --seeds 1",
    "experiment-out-unicode": "experiment assignment --quick --out 'éxp 实验' --seeds 1",
    "demo-quick": "demo --quick --out d",
    "demo-out-unicode": "demo --quick --out 'démo 演示' --quiet",
    "demo-out-existing-folder": "demo --quick --out . --quiet",
}
LEGAL_SETUP: dict[str, dict[str, Any]] = {
    "train-force": {"copy": ("net.npz",)},
    "quantize-force": {"copy": ("models",)},
    "export-into-existing-export": {
        "copy": ("deploy",),
        "note": "--force replaces an earlier export whole",
    },
    "report-in-place": {"copy": ("rep",)},
    "report-json-file": {"copy": ("rep",)},
    "report-combine-copies": {"copy": ("rep", "rep->rep2")},
}


def contained_file_cases() -> list[Case]:
    """A deploy folder whose export.json names a file outside it (``..``, absolute, a symbolic link out):
    ``localize --onnx DIR`` refuses it instead of running that file (issue 31)."""
    return [
        bad(
            f"localize-onnx-deploy-{name}",
            "localize",
            M8,
            "--onnx",
            f"{{fx}}/deploy_{name}",
            "--frames",
            "{fx}/nord/summer",
        )
        for name in ("parent", "dotdot", "absolute", "symlink")
    ]


def stream_cases() -> list[Case]:
    """A stream of frames cropped or rescaled from the reference images' size is refused before any decision;
    bags, event recordings, a cut video and an image too large for --memory-limit are one line (issue 31)."""
    frames = ("localize", M8, "--threshold", "0.5", "--frames")
    return [
        *(
            bad(f"localize-frames-{name}", *frames, f"{{fx}}/frames_{name}")
            for name in ("cropped", "rescaled", "one-pixel")
        ),
        # a flat frame carries no place: it runs, and its decision is none ("reason": "no contrast")
        legal("localize-frames-flat", *frames, "{fx}/frames_flat", note="no decision on a flat frame"),
        bad("localize-stream-huge-png", *frames, "{fx}/frames_huge", "--memory-limit", "100M"),
        bad("localize-stream-bag-two-topics", *frames, "{fx}/bag_two"),
        bad("localize-stream-bag-no-such-topic", *frames, "{fx}/bag_two", "--topic", "/depth"),
        bad("localize-stream-bag-damaged", *frames, "{fx}/damaged.bag"),
        bad(
            "localize-stream-bag-raw-over-memory-limit",
            *frames,
            "{fx}/bag_big",
            "--memory-limit",
            "100M",
            says="reading message 0 of /camera in",
            note="an 8000 x 8000 mono8 message: refused before it is deserialised, not after (as a wrong size)",
        ),
        bad("localize-stream-topic-not-a-bag", *frames, "{fx}/nord/winter", "--topic", "/camera"),
        bad("localize-stream-events-no-window", *frames, "{fx}/events.npy"),
        bad("localize-stream-events-window-0", *frames, "{fx}/events.npy", "--event-window-us", "0"),
        bad("localize-stream-events-count-digits", *frames, "{fx}/events.npy", "--event-count", "1_0"),
        bad("localize-stream-events-other-sensor", *frames, "{fx}/events_wide.npy", "--event-count", "100"),
        bad("localize-stream-events-pickle", *frames, "{fx}/events_pickle.npy", "--event-count", "100"),
        bad("localize-stream-events-empty", *frames, "{fx}/events_empty.txt", "--event-count", "100"),
        bad("localize-stream-video-cut", *frames, "{fx}/cut.avi"),
    ]


def operating_point_cases() -> list[Case]:
    """A tampered operating point (threshold -1, 0, NaN, text; precision 5; 5000-deep; 5001 digits) is refused."""
    return [
        bad(
            f"localize-point-{name}",
            "localize",
            M8,
            "--frames",
            "{fx}/nord/summer",
            "--operating-point",
            f"{{fx}}/point_{name}.json",
        )
        for name in POINT_EDITS
    ]


def ground_truth_cases() -> list[Case]:
    """Malformed, mismatched and code-running ground truth beside a folder data set (issue 31): every
    command that reads the pair refuses it with one line, and no pickle inside it runs."""
    cases = []
    for name in ground_truth_variants(12):
        data = f"{{fx}}/gt_{name}"
        two = ("train", "--data", data, "--reference", "summer,winter", *TINY, "--out", "t.npz")
        cases.append(bad(f"train-gt-{name}", *two))
        cases.append(bad(f"evaluate-gt-{name}", *EVAL, "--data", data, "--baseline"))
    unaligned = ("--data", "{fx}/gt_unaligned", "--query", "winter")  # 12 and 9 frames, no ground truth
    cases += [
        bad("evaluate-gt-unaligned", "evaluate", CK, *unaligned),
        bad("simulate-gt-unaligned", "simulate", M8, *unaligned),
        bad("localize-gt-unaligned", "localize", CK, "--calibrate", "winter", *unaligned[:2], "--quiet"),
        bad("verify-gt-unaligned", "verify", CK, "--bits", "8", *unaligned, "--report", "v"),
        bad("evaluate-gt-window-beside-file", *EVAL, "--data", "{fx}/gt_offset", "--match-window", "2"),
        legal(
            "evaluate-gt-predictions-truth",
            *EVAL,
            "--data",
            "{fx}/gt_offset",
            "--predictions",
            "p.jsonl",
            check="predictions-truth-offset-3",
            note="the truth column holds the file's places (query j: [j + 3]), not the frame index",
        ),
        legal("experiment-data-folder-aligned", *EXPERIMENT, "--seeds", "1", "--data", "{fx}/exp_aligned"),
        bad(
            "experiment-data-gt-shifted",
            *EXPERIMENT,
            "--data",
            "{fx}/exp_shifted",
            says="experiments score query frame j as reference place j",
        ),
        bad(
            "experiment-data-unequal",
            *EXPERIMENT,
            "--data",
            "{fx}/exp_unequal",
            says="the traversals hold different numbers of frames",
        ),
        bad("experiment-data-gt-offset", *EXPERIMENT, "--data", "{fx}/gt_offset", says="different numbers of frames"),
    ]
    return cases


def predictions_truth_offset(cwd: Path, fx: Path, offset: int = 3) -> str | None:
    """``p.jsonl`` of evaluate on ``gt_offset`` (winter frame j is summer place j + 3): every row's truth is
    ``[j + 3]`` and ``correct`` says whether its place is in it; the problem found, else None."""
    path = cwd / "p.jsonl"
    if not path.is_file():
        return "no p.jsonl was written"
    rows = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
    wrong = [r for r in rows if r["truth"] != [r["query"] + offset] or r["correct"] != (r["place_id"] in r["truth"])]
    return (
        f"{len(wrong)} of {len(rows)} rows: truth is not the ground truth's place (first: {wrong[0]})"
        if wrong
        else None
    )


#: Checks of a legal extreme's output (``Case.check``): name -> (its folder, the fixtures) -> a problem or None.
OUTPUT_CHECKS: dict[str, Callable[[Path, Path], str | None]] = {
    "predictions-truth-offset-3": predictions_truth_offset,
}


def issue45_cases() -> list[Case]:
    """Issue 45: the regressions since the guards moved to the edges, and the silent wrong answers it found."""
    adapt = ("train", "--data", "{fx}/adapt_data", "--reference", "summer", "--adapt-from", "winter", "--adapt", "gain")
    return [
        bad("i45-verify-tolerance-500-points", *VERIFY, "--tolerance", "accuracy=5", says="fraction in [0, 1]"),
        bad("i45-verify-tolerance-share-above-1", *VERIFY, "--tolerance", "top1_agreement=1.5", says="fraction"),
        bad("i45-verify-tolerance-half-query", *VERIFY, "--tolerance", "query_slack=0.5", says="whole number"),
        bad("i45-verify-tolerance-twice", *VERIFY, "--tolerance", "accuracy=0.02,accuracy=0.03", says="given twice"),
        bad("i45-train-set-empty-segment", *TRAIN, "--set", "train..epochs=2", says="empty name between dots"),
        bad("i45-train-set-section-as-json", *TRAIN, "--set", 'early={"spikes": 5}', says="is a section"),
        bad("i45-evaluate-velocity-search-k1", *EVAL, "--velocity-search", "0.5:1.5:0.5", says="at k = 1"),
        bad("i45-evaluate-manifest-beside-gt", *EVAL, "--data", "{fx}/nord_gt", says="is ambiguous"),
        bad("i45-localize-onnx-bit-flipped",
            "localize", M8, "--frames", "{fx}/nord_frames/winter", "--onnx", "{fx}/deploy_flipped/model.onnx",
            says="differs from what export wrote",
        ),
        bad("i45-report-ragged-curves", "report", "{fx}/rep_ragged", "--out", "r", says="PR curve"),
        bad("i45-localize-events-clock-jump",
            "localize", M8, "--frames", "{fx}/events_jump.npy", "--event-window-us", "1", says="frames",
        ),
        bad("i45-train-adapt-out-over-a-frame", *adapt, *TINY, "--force", "--out", "{fx}/adapt_data/winter/x.npz",
            says="never replaces a frame"),
    ]  # fmt: skip


def legal_cases() -> list[Case]:
    return [legal(f"legal-{name}", *sh(text), **LEGAL_SETUP.get(name, {})) for name, text in LEGAL_LINES.items()]


def all_cases() -> list[Case]:
    """Every case, in a fixed order; ids are unique."""
    groups = (
        cli_cases,
        config_cases,
        train_cases,
        memory_cases,
        evaluate_cases,
        simulate_cases,
        quantize_cases,
        export_cases,
        verify_cases,
        experiment_cases,
        demo_cases,
        file_argument_cases,
        tamper_cases,
        report_cases,
        manifest_cases,
        ground_truth_cases,
        contained_file_cases,
        operating_point_cases,
        stream_cases,
        output_cases,
        issue45_cases,
        legal_cases,
    )
    cases = [case for group in groups for case in group()]
    repeated = [name for name, count in Counter(c.id for c in cases).items() if count > 1]
    if repeated:
        raise SystemExit(f"repeated case ids: {repeated}")
    return cases


# ---------------------------------------------------------------------------------------------- campaign


def expand(arg: str, fx: Path, ro: Path) -> str:
    return arg.replace("{fx}", str(fx)).replace("{ro}", str(ro))


def prepare(case: Case, work: Path, fx: Path, ro: Path) -> Path:
    """The case's own fresh folder with its copied fixtures and links."""
    cwd = work / case.id
    if cwd.exists():
        shutil.rmtree(cwd)
    cwd.mkdir(parents=True)
    for item in case.copy:
        name, _, renamed = item.partition("->")
        source, target = fx / name, cwd / (renamed or name)
        if source.is_dir():
            shutil.copytree(source, target, symlinks=True)
        else:
            shutil.copyfile(source, target)
    for name, target_name in case.links:
        link_target = expand(target_name, fx, ro)
        if not link_target.startswith("/"):
            (cwd / link_target).mkdir(parents=True, exist_ok=True)
        os.symlink(link_target, cwd / name)
    return cwd


def run_case(case: Case, run: Runner, work: Path, fx: Path, ro: Path) -> Outcome:
    cwd = prepare(case, work, fx, ro)
    argv = [expand(arg, fx, ro) for arg in case.argv]
    raw = run(argv, cwd)
    lines = stderr_lines(raw.stderr)
    klass, note = expected(case, classify(case, raw), lines, cwd, fx)
    return Outcome(
        id=case.id,
        command=case.command,
        line=shlex.join(["vprsnn-export", *case.argv]),
        legal=case.legal,
        klass=klass,
        rc=raw.rc,
        first_line=lines[0] if lines else "",
        last_line=lines[-1] if lines else "",
        seconds=round(raw.seconds, 2),
        runner=run.name,
        fork_class=None,
        note=note,
        stderr=raw.stderr[-3000:],
    )


def expected(case: Case, klass: str, lines: Sequence[str], cwd: Path, fx: Path) -> tuple[str, str]:
    """The class and note once the case's own expectation is applied: a clean refusal whose line lacks
    ``case.says``, or a legal run whose output fails ``case.check``, is "other" (the note says why)."""
    if klass == "clean" and case.says and case.says not in lines[0]:
        return "other", f"refused for another reason: expected {case.says!r} in the error"
    if klass == "ran" and case.check:
        problem = OUTPUT_CHECKS[case.check](cwd, fx)
        if problem:
            return "other", f"ran, but {problem}"
    return klass, case.note


def confirm(case: Case, first: Outcome, run: ExecRunner, work: Path, fx: Path, ro: Path) -> Outcome:
    """A finding of the fork runner, run again as a real process: that result is kept (with the fork class)."""
    again = run_case(case, run, work, fx, ro)
    return Outcome(**{**asdict(again), "fork_class": first.klass})


def progress(index: int, total: int, outcome: Outcome) -> None:
    confirmed = f" (fork: {outcome.fork_class})" if outcome.fork_class else ""
    print(f"[{index}/{total}] {outcome.klass:10s}{confirmed} {outcome.seconds:6.1f} s  {outcome.id}", file=sys.stderr)


def run_campaign(
    cases: Sequence[Case], run: Runner, exec_run: ExecRunner | None, work: Path, fx: Path, ro: Path
) -> list[Outcome]:
    outcomes = []
    for index, case in enumerate(cases, 1):
        outcome = run_case(case, run, work, fx, ro)
        if exec_run is not None and is_finding(outcome) and outcome.klass != "timeout":
            outcome = confirm(case, outcome, exec_run, work, fx, ro)
        progress(index, len(cases), outcome)
        outcomes.append(outcome)
        shutil.rmtree(work / case.id, ignore_errors=True)
    return outcomes


# ---------------------------------------------------------------------------------------------- api section


def api_outcome(record: Mapping[str, Any]) -> Outcome:
    """One call of tools/bad_input_api.py as a campaign outcome (classes: see the module docstring)."""
    klass = {"project": "clean", "foreign": "traceback", "write-then-refuse": "write-then-refuse"}.get(
        record["class"], "accepted"
    )
    is_legal = record["class"] == "accepted" and bool(record.get("legal"))
    detail = str(record.get("detail", ""))
    return Outcome(
        id=f"api-{record['case']}",
        command="(api)",
        line=f"vx.{record['case']}",
        legal=is_legal,
        klass="ran" if is_legal else klass,
        rc=0,
        first_line=detail,
        last_line=detail,
        seconds=0.0,
        runner="api",
        fork_class=None,
        note="",
        stderr="" if klass == "clean" else detail,
    )


def api_section(work: Path, timeout: float) -> list[Outcome]:
    """tools/bad_input_api.py in a child process; its cases as outcomes, or one ``crash``/``timeout`` outcome."""
    work.mkdir(parents=True, exist_ok=True)
    cases = work / "api_cases.json"
    started = time.perf_counter()
    try:
        done = subprocess.run(
            [sys.executable, str(API_TOOL), "--json", str(cases)],
            cwd=work,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            timeout=timeout,
        )
        raw = Raw(done.returncode, decode(done.stdout), decode(done.stderr), time.perf_counter() - started, False)
    except subprocess.TimeoutExpired as exc:
        raw = Raw(-9, decode(exc.stdout or b""), decode(exc.stderr or b""), time.perf_counter() - started, True)
    if raw.rc >= 0 and not raw.timed_out and cases.is_file():
        return [api_outcome(record) for record in json.loads(cases.read_text(encoding="utf-8"))["cases"]]
    klass = "timeout" if raw.timed_out else "crash" if raw.rc < 0 else "other"
    lines = stderr_lines(raw.stderr) or [f"rc {raw.rc}"]
    return [Outcome("api-run", "(api)", f"python {API_TOOL.name}", False, klass, raw.rc, lines[0], lines[-1],
                    round(raw.seconds, 2), "api", None, "", raw.stderr[-3000:])]  # fmt: skip


# ---------------------------------------------------------------------------------------------- fault section


@dataclass(frozen=True)
class Fault:
    """One fault case's result: the process's raw result and the checks that failed (empty: handled)."""

    id: str
    line: str
    raw: Raw
    failed: tuple[str, ...]


def fault_outcome(fault: Fault) -> Outcome:
    lines = stderr_lines(fault.raw.stderr)
    if fault.raw.timed_out:
        klass = "timeout"
    elif "Traceback" in fault.raw.stderr:
        klass = "traceback"
    elif fault.failed:
        klass = "other"
    else:
        klass = "clean"
    return Outcome(
        id=fault.id,
        command="(faults)",
        line=fault.line,
        legal=False,
        klass=klass,
        rc=fault.raw.rc,
        first_line=lines[0] if lines else "",
        last_line=lines[-1] if lines else "",
        seconds=round(fault.raw.seconds, 2),
        runner="exec",
        fork_class=None,
        note="; ".join(fault.failed),
        stderr=fault.raw.stderr[-3000:],
    )


def start(program: str, argv: Sequence[str], cwd: Path, stdout: Any = subprocess.DEVNULL) -> subprocess.Popen:
    return subprocess.Popen(
        [program, *argv], cwd=cwd, stdin=subprocess.DEVNULL, stdout=stdout, stderr=subprocess.PIPE,
        start_new_session=True,
    )  # fmt: skip


def finish(process: subprocess.Popen, started: float, timeout: float) -> Raw:
    """Wait for ``process``; its stderr, exit code (-signal when killed) and wall time."""
    timed_out = False
    try:
        _, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        timed_out = True
        os.killpg(process.pid, signal.SIGKILL)
        _, err = process.communicate()
    return Raw(process.returncode, "", decode(err or b""), time.perf_counter() - started, timed_out)


def kill_while_writing(program: str, argv: Sequence[str], cwd: Path, watch: Path, timeout: float) -> tuple[Raw, bool]:
    """Run ``argv`` and SIGKILL it as soon as a temp file (``.NAME.*.tmp``) appears in ``watch``.

    Returns the killed (or finished) run and whether the kill came while a temp file was there.
    """
    started = time.perf_counter()
    process = start(program, argv, cwd)
    caught = False
    while process.poll() is None and time.perf_counter() - started < timeout:
        if watch.is_dir() and any(watch.glob(".*.tmp")):
            os.killpg(process.pid, signal.SIGKILL)
            caught = True
            break
        time.sleep(0.0005)
    return finish(process, started, timeout), caught


def loads(path: Path) -> str | None:
    """None when the project's reader for ``path`` loads it whole; else the reader's error."""
    vx = importlib.import_module("vprsnn_export")
    try:
        with np.load(path, allow_pickle=False) as npz:
            meta = json.loads(npz["__meta__"].tobytes().decode("utf-8"))
        kind = meta.get("format", meta.get("kind", ""))  # a fixed-point model's header names its "format"
        reader = vx.load_fixed_point if "fixed" in str(kind) else vx.load_checkpoint
        reader(path)
    except Exception as exc:  # noqa: BLE001  (any failure to read is the finding)
        return f"{path.name} does not load: {type(exc).__name__}: {str(exc)[:120]}"
    return None


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.glob(".*") if p.name.endswith(".tmp") or ".staging-" in p.name)


def sigkill_fault(program: str, fault_id: str, argv: Sequence[str], cwd: Path, out: Path, timeout: float) -> Fault:
    """SIGKILL while ``argv`` writes into ``out`` (a folder or the folder of an output file), then the next run.

    Checks: the kill came during a write (up to 5 tries); every visible .npz left loads; the next run
    (``--force``) succeeds and leaves no temp file behind.
    """
    folder = out if out.suffix != ".npz" else out.parent
    failed: list[str] = []
    caught = False
    raw = Raw(0, "", "", 0.0, False)
    for _ in range(5):
        if folder == cwd:
            out.unlink(missing_ok=True)
        else:
            shutil.rmtree(folder, ignore_errors=True)
        raw, caught = kill_while_writing(program, argv, cwd, folder, timeout)
        if caught or raw.timed_out:
            break
    if not caught:
        failed.append("no kill landed while a temp file was being written (5 tries)")
    visible = [out] if out.suffix == ".npz" else sorted(folder.rglob("*.npz")) if folder.is_dir() else []
    failed += [problem for path in visible if path.is_file() and (problem := loads(path))]
    left_before = leftovers(folder) if folder.is_dir() else []
    again = finish(start(program, [*argv, "--force"], cwd), time.perf_counter(), timeout)
    if again.rc != 0:
        failed.append(f"the next run failed (rc {again.rc}): {(stderr_lines(again.stderr) or [''])[-1]}")
    left_after = leftovers(folder) if folder.is_dir() else []
    if left_after:
        failed.append(f"the next run left {left_after} (before it: {left_before})")
    line = shlex.join(["vprsnn-export", *argv]) + "  # SIGKILL while writing, then again with --force"
    stderr = raw.stderr if "Traceback" in raw.stderr else again.stderr
    return Fault(fault_id, line, Raw(again.rc, "", stderr, raw.seconds + again.seconds, again.timed_out), tuple(failed))


def stdout_fault(program: str, fault_id: str, argv: Sequence[str], cwd: Path, timeout: float, full: bool) -> Fault:
    """Standard output on /dev/full (exit 1, one line ``error: cannot write the standard output``) or on a
    pipe whose reader has gone (exit 141 as for SIGPIPE, nothing on stderr)."""
    started = time.perf_counter()
    if full:
        with open("/dev/full", "wb") as sink:
            raw = finish(start(program, argv, cwd, stdout=sink), started, timeout)
        expected_rc, expected = 1, "error: cannot write the standard output"
    else:
        process = start(program, argv, cwd, stdout=subprocess.PIPE)
        assert process.stdout is not None
        process.stdout.close()  # the reader is gone before the first write
        raw = finish(process, started, timeout)
        expected_rc, expected = 128 + signal.SIGPIPE, ""
    lines = stderr_lines(raw.stderr)
    failed = []
    if raw.rc != expected_rc:
        failed.append(f"exit {raw.rc}, expected {expected_rc}")
    if (lines[-1:] if lines else [""])[0][: len(expected)] != expected or len(lines) > (1 if expected else 0):
        failed.append(f"stderr {lines[:3]!r}, expected {'one line ' + repr(expected) if expected else 'nothing'}")
    where = "> /dev/full" if full else "| (closed pipe)"
    return Fault(fault_id, shlex.join(["vprsnn-export", *argv]) + f" {where}", raw, tuple(failed))


def mapped(pid: int, needle: str) -> bool:
    """Whether process ``pid`` has a file whose path contains ``needle`` mapped (Linux /proc)."""
    try:
        return needle in Path(f"/proc/{pid}/maps").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return False


def interrupt_fault(program: str, fault_id: str, argv: Sequence[str], cwd: Path, after: float, timeout: float) -> Fault:
    """Ctrl-C (SIGINT) while the command starts: ``after`` seconds once torch's libraries are being mapped
    (the command's own start-up: package, command module, torch, numba), the guard of startup.py
    standing; expected: exit 130 with the one line ``error: interrupted``."""
    started = time.perf_counter()
    process = start(program, argv, cwd)
    failed = []
    while process.poll() is None and not mapped(process.pid, "/torch/") and time.perf_counter() - started < timeout:
        time.sleep(0.001)
    time.sleep(after)
    if process.poll() is not None:
        failed.append(f"the command ended before the interrupt ({after} s after torch began to load)")
    else:
        process.send_signal(signal.SIGINT)
    raw = finish(process, started, timeout)
    lines = stderr_lines(raw.stderr)
    if raw.rc != 130 or lines != ["error: interrupted"]:
        failed.append(f"exit {raw.rc} with stderr {lines[:3]!r}, expected 130 and 'error: interrupted'")
    line = shlex.join(["vprsnn-export", *argv]) + f"  # SIGINT {after} s after torch began to load"
    return Fault(fault_id, line, raw, tuple(failed))


def cluster_fault(program: str, fault_id: str, argv: Sequence[str], cwd: Path, timeout: float) -> Fault:
    """SIGKILL of the command alone (not its process group) while its tasks run on the local Ray cluster it
    started (issue 31): every process it started must end within 15 s (those left are then killed, by pid)."""
    cluster = importlib.import_module("vprsnn_export.cluster")
    started = time.perf_counter()
    process = start(program, argv, cwd)
    below: dict[int, str] = {}
    failed = []
    while process.poll() is None and time.perf_counter() - started < timeout:
        below = cluster.descendants(process.pid, cluster.process_table())
        if any(
            b"ray::_timed" in Path(f"/proc/{pid}/cmdline").read_bytes()
            for pid in below
            if os.path.exists(f"/proc/{pid}")
        ):
            break
        time.sleep(0.2)
    if process.poll() is not None:
        failed.append("the command ended before its Ray tasks ran")
    os.kill(process.pid, signal.SIGKILL)
    raw = finish(process, started, timeout)

    def running() -> list[int]:
        table = cluster.process_table()
        return [pid for pid, start in below.items() if table.get(pid, (0, ""))[1] == start]

    deadline = time.perf_counter() + 15
    while running() and time.perf_counter() < deadline:
        time.sleep(0.5)
    left = running()
    if left:
        failed.append(f"{len(left)} of its {len(below)} processes still ran 15 s after the SIGKILL")
    for pid in left:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
    line = shlex.join(["vprsnn-export", *argv]) + "  # SIGKILL of the command while its Ray tasks run"
    return Fault(fault_id, line, Raw(raw.rc, "", "", raw.seconds, raw.timed_out), tuple(failed))


def fault_section(work: Path, fx: Path, timeout: float, only: str | None) -> list[Outcome]:
    """The fault cases (see the module docstring), each in its own folder under ``work``."""
    program = ExecRunner(timeout).program
    ck = str(fx / "net.npz")
    train = [*sh(T_TINY), "--quiet"]
    cases: dict[str, Callable[[Path], Fault]] = {
        "fault-sigkill-quantize": lambda cwd: sigkill_fault(
            program, "fault-sigkill-quantize", ["quantize", ck, "--bits", "2,3,4,5,6,7,8", "--out", "q", "--quiet"],
            cwd, cwd / "q", timeout),
        "fault-sigkill-train": lambda cwd: sigkill_fault(
            program, "fault-sigkill-train", [*train, "--out", "t.npz"], cwd, cwd / "t.npz", timeout),
        "fault-sigkill-cluster-local": lambda cwd: cluster_fault(
            program, "fault-sigkill-cluster-local",
            [*train, "--epochs", "200", "--module-size", "8", "--cluster", "local:2", "--out", "c.npz"], cwd, timeout),
        "fault-dev-full-help": lambda cwd: stdout_fault(program, "fault-dev-full-help", ["--help"], cwd, timeout, True),
        "fault-dev-full-evaluate": lambda cwd: stdout_fault(
            program, "fault-dev-full-evaluate", ["evaluate", ck, "--query", "winter"], cwd, timeout, True),
        "fault-closed-pipe-help": lambda cwd: stdout_fault(
            program, "fault-closed-pipe-help", ["--help"], cwd, timeout, False),
        "fault-closed-pipe-evaluate": lambda cwd: stdout_fault(
            program, "fault-closed-pipe-evaluate", ["evaluate", ck, "--query", "winter"], cwd, timeout, False),
        **{f"fault-ctrl-c-startup-{delay}s": (lambda cwd, delay=delay: interrupt_fault(
            program, f"fault-ctrl-c-startup-{delay}s", [*train, "--out", "i.npz"], cwd, delay, timeout))
           for delay in (0.0, 0.1, 0.3, 1.0)},
    }  # fmt: skip
    outcomes = []
    chosen = [name for name in cases if not only or only in name]
    for index, name in enumerate(chosen, 1):
        cwd = work / name
        shutil.rmtree(cwd, ignore_errors=True)
        cwd.mkdir(parents=True)
        outcome = fault_outcome(cases[name](cwd))
        progress(index, len(chosen), outcome)
        outcomes.append(outcome)
        shutil.rmtree(cwd, ignore_errors=True)
    return outcomes


# ---------------------------------------------------------------------------------------------- writing


def counts(outcomes: Sequence[Outcome], is_legal: bool) -> Counter[str]:
    return Counter(o.klass for o in outcomes if o.legal == is_legal)


def counts_table(outcomes: Sequence[Outcome]) -> str:
    """Markdown tables: totals by class, then by command."""
    bad_counts, legal_counts = counts(outcomes, False), counts(outcomes, True)
    lines = [
        "| bad inputs | " + " | ".join(BAD_CLASSES) + " | total |",
        "|---|" + "---:|" * (len(BAD_CLASSES) + 1),
        "| all | " + " | ".join(str(bad_counts[c]) for c in BAD_CLASSES) + f" | {sum(bad_counts.values())} |",
        "",
        "| legal extremes | " + " | ".join(LEGAL_CLASSES) + " | total |",
        "|---|" + "---:|" * (len(LEGAL_CLASSES) + 1),
        "| all | " + " | ".join(str(legal_counts[c]) for c in LEGAL_CLASSES) + f" | {sum(legal_counts.values())} |",
        "",
        "| command | bad | " + " | ".join(BAD_CLASSES) + " | legal | ran | not ran |",
        "|---|" + "---:|" * (len(BAD_CLASSES) + 4),
    ]
    for command in (*COMMANDS, "(none)", "(api)", "(faults)"):
        mine = [o for o in outcomes if o.command == command]
        if not mine:
            continue
        bad_here, legal_here = counts(mine, False), counts(mine, True)
        cells = [str(sum(bad_here.values())), *(str(bad_here[c]) for c in BAD_CLASSES)]
        cells += [
            str(sum(legal_here.values())),
            str(legal_here["ran"]),
            str(sum(legal_here.values()) - legal_here["ran"]),
        ]
        lines.append(f"| {command} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def finding_text(outcome: Outcome) -> str:
    kind = "legal extreme" if outcome.legal else "bad input"
    confirmed = f"; fork runner: {outcome.fork_class}" if outcome.fork_class else ""
    note = f"; note: {outcome.note}" if outcome.note else ""
    tail = outcome.stderr.strip().splitlines()[-8:]
    block = "\n".join("    " + line[:300] for line in tail) if tail else "    (stderr empty)"
    return (
        f"* `{outcome.id}` ({kind}, rc {outcome.rc}, {outcome.runner}{confirmed}{note})\n"
        f"  `{outcome.line}`\n\n{block}\n"
    )


def markdown(outcomes: Sequence[Outcome], command: str, seconds: float) -> str:
    findings = [o for o in outcomes if is_finding(o)]
    parts = [
        "# Bad-input campaign (issues 12 and 24): command line, library, faults\n",
        f"`{command}`: {len(outcomes)} cases in {seconds:.0f} s, {time.strftime('%Y-%m-%d %H:%M')}.\n",
        "Classes: see the docstring of tools/bad_input_campaign.py.\n",
        "## Counts\n",
        counts_table(outcomes),
        f"\n## Cases that are not clean ({len(findings)})\n",
    ]
    for klass in (*BAD_CLASSES, *LEGAL_CLASSES):
        group = [o for o in findings if o.klass == klass]
        if group:
            parts.append(f"### {klass} ({len(group)})\n")
            parts += [finding_text(o) for o in group]
    return "\n".join(parts) + "\n"


def write_results(out: Path, outcomes: Sequence[Outcome], command: str, seconds: float) -> None:
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for outcome in outcomes:
        record = asdict(outcome)
        record["class"] = record.pop("klass")
        if not is_finding(outcome):
            record.pop("stderr")
        records.append(record)
    summary = {
        "bad": dict(counts(outcomes, False)),
        "legal": dict(counts(outcomes, True)),
        "seconds": round(seconds, 1),
        "command": command,
    }
    text = json.dumps({"summary": summary, "cases": records}, indent=1, ensure_ascii=False)
    (out / "bad_inputs.json").write_text(text + "\n", encoding="utf-8")
    (out / "bad_inputs.md").write_text(markdown(outcomes, command, seconds), encoding="utf-8")


# ---------------------------------------------------------------------------------------------- main


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, type=Path, help="folder for bad_inputs.json and bad_inputs.md")
    parser.add_argument("--only", help="run only the cases whose id or command line contains this text")
    parser.add_argument("--exec", action="store_true", help="run every case as a fresh vprsnn-export process")
    parser.add_argument("--no-confirm", action="store_true", help="keep the fork runner's result of every case")
    parser.add_argument("--timeout", type=float, default=TIMEOUT_S, help="seconds per case (default 60)")
    parser.add_argument("--nordland", type=Path, default=NORDLAND, help="the shared Nordland data, for manifests")
    parser.add_argument("--keep", action="store_true", help="keep the temp folder (fixtures, logs)")
    parser.add_argument("--list", action="store_true", help="print the case ids and command lines, run nothing")
    parser.add_argument(
        "--sections", default=",".join(SECTIONS), help=f"comma-separated sections to run (default {','.join(SECTIONS)})"
    )
    return parser.parse_args(argv)


def selected(cases: Sequence[Case], only: str | None) -> list[Case]:
    if not only:
        return list(cases)
    return [c for c in cases if only in c.id or only in shlex.join(c.argv)]


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    sections = [name for name in args.sections.split(",") if name]
    if not sections or any(name not in SECTIONS for name in sections):
        raise SystemExit(f"--sections: choose from {', '.join(SECTIONS)}")
    cases = selected(all_cases(), args.only) if "cli" in sections else []
    if args.list:
        for case in cases:
            print(f"{'legal' if case.legal else 'bad  '} {case.id}: {shlex.join(case.argv)}")
        return 0
    started = time.perf_counter()
    temp = Path(tempfile.mkdtemp(prefix="vprsnn-campaign-"))
    os.environ.update(OMP_NUM_THREADS="1", VPRSNN_CACHE=str(temp / "cache"))
    fx, work, logs = temp / "fixtures", temp / "cases", temp / "logs"
    logs.mkdir()
    exec_run = ExecRunner(args.timeout)
    run: Runner = exec_run if args.exec else ForkRunner(args.timeout, logs)
    ro = temp / "readonly"
    try:
        build_fixtures(fx, run, args.nordland)
        ro = make_readonly(ro)
        print(f"fixtures ready in {time.perf_counter() - started:.0f} s; {len(cases)} cases", file=sys.stderr)
        confirm_run = None if args.exec or args.no_confirm else exec_run
        outcomes = run_campaign(cases, run, confirm_run, work, fx, ro)
        if "api" in sections and (not args.only or args.only in "api"):
            outcomes += api_section(work / "api", timeout=20 * 60)
        if "faults" in sections:
            outcomes += fault_section(work / "faults", fx, args.timeout, args.only)
    finally:
        release_readonly(temp / "readonly")
        if not args.keep:
            shutil.rmtree(temp, ignore_errors=True)
    seconds = time.perf_counter() - started
    command = shlex.join(["python", "tools/bad_input_campaign.py", *(sys.argv[1:] if argv is None else argv)])
    write_results(args.out, outcomes, command, seconds)
    print(counts_table(outcomes))
    print(f"\n{len(outcomes)} cases in {seconds:.0f} s; details: {args.out / 'bad_inputs.md'}")
    return 1 if any(is_finding(o) for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
