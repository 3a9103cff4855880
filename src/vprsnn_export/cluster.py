"""Independent tasks on a cluster engine (Ray) or in this process: the `--cluster` option.

Modules of an ensemble are independent until the readout, so training and spike counting
split into one task per module. A task is a module-level function and its arguments; it runs

    in this process               (no cluster: the plain loop, the reference)
    on a local Ray cluster        ("local" or "local:N": N worker processes on this machine)
    on a running Ray cluster      ("ray://HOST:PORT" through Ray Client, or "auto" on a node
                                   of a cluster started with `ray start`)

and the results come back in the order of the tasks. Every worker needs this package (the
same version) importable; the data travel with the tasks, so workers need no data path.
Ray is optional (``pip install "vprsnn-export[cluster]"``) and imported only when a cluster is used.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from tqdm import tqdm

from .data.preprocess import captured_stderr
from .errors import InvalidValueError

CLUSTER_HELP = "local, local:N (N worker processes here), ray://HOST:PORT or auto (a running Ray cluster)"
#: Seconds between two looks of the watchdog at the processes of a local Ray cluster (:func:`watch_cluster`).
WATCH_INTERVAL_S = 0.5
#: Rounds of killing once the command has ended: each also takes the children the survivors started meanwhile.
KILL_ROUNDS = 4
#: Seconds to wait for a ray:// head to accept a connection before giving up (Ray Client alone retries for 35 s).
CONNECT_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class Cluster:
    """Where tasks run: ``address`` is "local" (a Ray cluster started here), "auto" or "ray://HOST:PORT"."""

    address: str
    workers: int | None = None  # local: worker processes (None: the CPU count)
    threads: int = 1  # torch threads in each task


def parse_cluster(text: str, *, threads: int | None = None, option: str = "--cluster") -> Cluster:
    """'local', 'local:N', 'auto' or 'ray://HOST:PORT' -> Cluster; InvalidValueError naming ``option`` otherwise."""
    value = str(text).strip()
    count = 1 if threads is None else threads
    match = re.fullmatch(r"local(?::(\d+))?", value)
    if match:
        workers = None if match.group(1) is None else int(match.group(1))
        if workers is not None and not 1 <= workers <= 4096:
            raise InvalidValueError(f"{option}: local:N needs N from 1 to 4096, got {value!r}")
        if workers is not None and count > workers:
            raise InvalidValueError(
                f"{option}: each task takes --threads {count} CPU slots, more than the {workers} of {value!r}"
            )
        return Cluster("local", workers, count)
    match = re.fullmatch(r"ray://[A-Za-z0-9._\-\[\]:]+:(\d{1,5})", value)
    if match and not 1 <= int(match.group(1)) <= 65535:
        raise InvalidValueError(f"{option}: the port of {value!r} is not from 1 to 65535")
    if match or value == "auto":
        return Cluster(value, None, count)
    raise InvalidValueError(f"{option}: expected {CLUSTER_HELP}, got {text!r}")


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise InvalidValueError(
            '--cluster needs Ray: pip install -c constraints.txt "vprsnn-export[cluster]"'
        ) from None
    return ray


@dataclass(frozen=True)
class TaskTiming:
    """Wall time of one map: the whole map and the sum of the tasks' own run times."""

    wall_seconds: float
    task_seconds: tuple[float, ...]


def _timed(threads: int | None, function: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """On a worker: fix the torch thread count (None: in this process, left as it is), then run the task, timed."""
    started = time.perf_counter()
    if threads is not None:
        import torch  # a worker process starts bare

        torch.set_num_threads(threads)
    return function(*args), time.perf_counter() - started


def task_bar(tasks: Sequence[Any], desc: str | None) -> tqdm:
    """A bar on stderr over finished tasks (none when ``desc`` is None); closed on any exception (``leave=False``)."""
    return tqdm(tasks, total=len(tasks), desc=desc, unit="task", file=sys.stderr, leave=False, disable=desc is None)


def map_tasks(
    cluster: Cluster | None,
    function: Callable[..., Any],
    tasks: Sequence[tuple],
    *,
    timing: list | None = None,
    progress: str | None = None,
) -> list[Any]:
    """[function(*task) for task in tasks], on the cluster's workers (in parallel) or here when ``cluster`` is None.

    Arguments shared by several tasks should be the same object: Ray stores each once. A Ray
    runtime this call starts is shut down before it returns; one already running (``ray.init``
    by the caller) is used and left running. ``timing``: a TaskTiming is appended. ``progress``:
    the description of a bar on stderr that counts finished tasks (None: no bar).
    """
    started = time.perf_counter()
    if cluster is None:
        with task_bar(tasks, progress) as bar:
            pairs = [_timed(None, function, *task) for task in bar]
    else:
        pairs = _ray_map(cluster, function, tasks, progress)
    if timing is not None:
        timing.append(TaskTiming(time.perf_counter() - started, tuple(seconds for _, seconds in pairs)))
    return [result for result, _ in pairs]


def _ray_map(
    cluster: Cluster, function: Callable[..., Any], tasks: Sequence[tuple], progress: str | None
) -> list[tuple[Any, float]]:
    ray = _ray()
    started_here = not ray.is_initialized()
    watchdog = start_watchdog() if started_here and cluster.address == "local" else None
    try:
        if started_here:
            connect(ray, cluster)
        remote = ray.remote(num_cpus=cluster.threads)(_timed)
        shared: dict[int, Any] = {}

        def stored(value: Any) -> Any:
            """Large arrays go to the object store once, however many tasks share them."""
            if getattr(value, "nbytes", 0) < 1 << 16:
                return value
            if id(value) not in shared:
                shared[id(value)] = ray.put(value)
            return shared[id(value)]

        refs = [remote.remote(cluster.threads, function, *(stored(a) for a in task)) for task in tasks]
        with task_bar(refs, progress) as bar:
            pending = list(refs)
            while pending:  # as tasks finish, in any order; the results below keep the tasks' order
                ready, pending = ray.wait(pending, num_returns=1)
                bar.update(len(ready))
        return list(ray.get(refs))
    finally:
        if started_here and ray.is_initialized():
            ray.shutdown()
        stop_watchdog(watchdog)


def connect(ray: Any, cluster: Cluster) -> None:
    """Start (local) or join (auto, ray://) a Ray runtime for this process (``ray``: the imported module)."""
    if cluster.address.startswith("ray://"):
        reachable(cluster.address)
    try:
        if cluster.address == "local":
            keep_ray_notices_back()  # nothing above a later one-line error
            ray.init(
                num_cpus=cluster.workers or max(os.cpu_count() or 1, cluster.threads),
                include_dashboard=False,
                log_to_driver=False,
                configure_logging=False,
            )
        else:
            # Ray Client logs its retries from C++ and Python alike: held back, written out once it succeeds
            with captured_stderr() as caught:
                ray.init(address=cluster.address, log_to_driver=False, configure_logging=False)
            sys.stderr.writelines(f"{line}\n" for line in caught)
    except Exception as exc:  # Ray raises ConnectionError, RuntimeError, ValueError... for an unreachable cluster
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InvalidValueError(f"--cluster {cluster.address}: cannot start or reach Ray ({reason})") from None


def reachable(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Nothing when the head of ``ray://HOST:PORT`` accepts a TCP connection within ``timeout`` seconds;
    InvalidValueError naming the address otherwise (Ray Client would retry for 35 s and log each try)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as exc:
        raise InvalidValueError(
            f"--cluster {address}: no Ray head answers there within {timeout:g} s ({exc.strerror or exc})"
        ) from None


#: Lines Ray logs on every start that say nothing about this run (its token-authentication notice).
RAY_NOTICES = ("Token authentication is enabled for this Ray cluster",)
RAY_NOTICE_LOGGER = "ray._private.authentication.authentication_token_setup"


class _NoNotice(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(RAY_NOTICES)


def keep_ray_notices_back() -> None:
    """Drop :data:`RAY_NOTICES` from Ray's logger (once): Python's last-resort handler would print them on stderr.
    File descriptor 2 is left as it is: the agents a local cluster starts inherit it (redirecting it around
    ``ray.init`` left them running after a SIGKILL, tests/commands/test_cluster_hardening.py)."""
    notices = logging.getLogger(RAY_NOTICE_LOGGER)
    if not any(isinstance(f, _NoNotice) for f in notices.filters):
        notices.addFilter(_NoNotice())


# ---------------------------------------------------------------------------- a local cluster ends with the command


def process_table() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, start time in clock ticks since boot) of every running process (zombies left out),
    from /proc (Linux)."""
    table = {}
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                with open(f"/proc/{entry.name}/stat", encoding="ascii", errors="replace") as handle:
                    fields = handle.read().rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, ...
            except (OSError, IndexError):
                continue
            if fields[0] != "Z":  # a zombie has ended already
                table[int(entry.name)] = (int(fields[1]), fields[19])  # fields 4 and 22 of proc(5)
    return table


def descendants(root: int, table: dict[int, tuple[int, str]]) -> dict[int, str]:
    """pid -> start time of every process below ``root`` in ``table`` (children, their children, ...)."""
    children: dict[int, list[int]] = {}
    for pid, (parent, _) in table.items():
        children.setdefault(parent, []).append(pid)
    found: dict[int, str] = {}
    stack = list(children.get(root, ()))
    while stack:
        pid = stack.pop()
        if pid not in found:
            found[pid] = table[pid][1]
            stack += children.get(pid, ())
    return found


def watch_cluster(parent: int, parent_start: str, before: set[int]) -> None:
    """The watchdog of a local Ray cluster (a process of its own, :func:`start_watchdog`).

    Every WATCH_INTERVAL_S it notes the processes below ``parent`` other than ``before`` (those it had when it
    started this watchdog: a watchdog slow to load must not count Ray's first processes among them; Ray's
    GCS, raylet, agents and workers); when its standard input closes and ``parent`` has ended (whatever
    ended it, SIGKILL included: Ray's agents outlive their raylet), it kills those still running, each
    checked by its start time (a pid the system gave to another process is left alone), and then, for
    KILL_ROUNDS rounds, the processes those started meanwhile. A parent that
    closes the pipe itself (after ``ray.shutdown``) leaves everything as it is.
    """
    me = os.getpid()
    seen: dict[int, str] = {}
    while True:
        table = process_table()
        seen.update({pid: start for pid, start in descendants(parent, table).items() if pid not in before})
        seen.pop(me, None)
        ready, _, _ = select.select([0], [], [], WATCH_INTERVAL_S)
        if ready and not os.read(0, 4096):
            break
    if process_table().get(parent, (0, ""))[1] == parent_start:
        return  # the command shut its cluster down and goes on
    for _ in range(KILL_ROUNDS):  # a Ray process that outlived the command may still start workers: their turn next
        table = process_table()
        for pid in list(seen):
            seen.update(descendants(pid, table))
        for pid, start in seen.items():
            if table.get(pid, (0, ""))[1] == start:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
        time.sleep(WATCH_INTERVAL_S)


def start_watchdog() -> subprocess.Popen | None:
    """A :func:`watch_cluster` process for this one, in a session of its own (None where /proc is absent)."""
    me = os.getpid()
    table = process_table() if os.path.isdir("/proc") else {}
    if me not in table:
        return None
    before = ",".join(str(pid) for pid in descendants(me, table))
    code = (
        "import sys; from vprsnn_export.cluster import watch_cluster; "
        "watch_cluster(int(sys.argv[1]), sys.argv[2], {int(p) for p in sys.argv[3].split(',') if p})"
    )
    return subprocess.Popen(
        [sys.executable, "-c", code, str(me), table[me][1], before],
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)},
    )


def stop_watchdog(watchdog: subprocess.Popen | None) -> None:
    """Close the watchdog's pipe (this process lives on: it kills nothing) and wait for it to end."""
    if watchdog is not None and watchdog.stdin is not None:
        watchdog.stdin.close()
        try:
            watchdog.wait(timeout=10 * WATCH_INTERVAL_S)
        except subprocess.TimeoutExpired:
            watchdog.kill()
            watchdog.wait()
