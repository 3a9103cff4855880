"""A Ctrl-C while the command loads exits 130 with one line: the guard of vprsnn_export.startup."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vprsnn_export.startup import (
    InterruptsHeld,
    end_guard,
    install_guard,
    interrupted_while_loading,
    started_as_command,
)


@pytest.mark.parametrize(
    ("argv0", "orig_argv", "expected"),
    [
        ("/venv/bin/vprsnn-export", ["/venv/bin/python", "/venv/bin/vprsnn-export", "train"], True),
        ("-m", ["python", "-m", "vprsnn_export", "train"], True),
        ("-m", ["python3.11", "-X", "importtime", "-W", "ignore", "-u", "-mvprsnn_export"], True),
        ("-m", ["python", "-m", "vprsnn_export.__main__", "--help"], True),
        ("-m", ["python", "-m", "pytest", "-m", "vprsnn_export"], False),
        ("script.py", ["python", "script.py", "-m", "vprsnn_export"], False),
        ("-c", ["python", "-c", "import vprsnn_export", "-m", "vprsnn_export"], False),
        ("", ["python"], False),
        ("/usr/bin/vprsnn-export-old", ["python", "/usr/bin/vprsnn-export-old"], False),
    ],
)
def test_started_as_command(argv0, orig_argv, expected):
    assert started_as_command(argv0, orig_argv) is expected


def test_the_handler_prints_one_line_and_exits_130(capsys):
    with pytest.raises(SystemExit) as info:
        interrupted_while_loading(signal.SIGINT, None)
    assert info.value.code == 130
    assert capsys.readouterr() == ("", "error: interrupted\n")


def test_the_guard_takes_sigint_from_python_only_and_gives_it_back():
    before = signal.getsignal(signal.SIGINT)
    try:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        install_guard()
        assert signal.getsignal(signal.SIGINT) is interrupted_while_loading
        end_guard()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a job started in the background: Ctrl-C stays ignored
        install_guard()
        end_guard()
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


def test_an_interrupt_held_while_torch_loads_arrives_when_the_block_ends():
    """set_threads imports torch inside InterruptsHeld: a Ctrl-C there (raised inside torch's C++ start-up it would
    abort the process) is noted and raised as KeyboardInterrupt at the block's end, which main turns into one line."""
    before = signal.getsignal(signal.SIGINT)
    finished = False
    try:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        with pytest.raises(KeyboardInterrupt):
            with InterruptsHeld():
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)  # a delivered SIGINT would have raised by now
                finished = True
        assert finished
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # given back
    finally:
        signal.signal(signal.SIGINT, before)


@pytest.mark.parametrize(("argv0", "guarded"), [("vprsnn-export", True), ("my_program.py", False)])
def test_importing_the_package_guards_the_command_only(argv0, guarded):
    probe = (
        # SIGINT as an interactive shell leaves it (a background job inherits it ignored, which the guard respects)
        "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        f"sys.argv[0] = {argv0!r}; import vprsnn_export; "
        "from vprsnn_export.startup import interrupted_while_loading as guard; "
        "print(signal.getsignal(signal.SIGINT) is guard)"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip() == str(guarded), done.stderr


def wait_for_library(process: subprocess.Popen, name: str, timeout: float = 120) -> None:
    """Until ``process`` has mapped a shared library whose path holds ``name`` (it is loading it)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and process.poll() is None:
        if name in Path(f"/proc/{process.pid}/maps").read_text():
            return
        time.sleep(0.002)
    pytest.fail(f"the command did not load {name} in {timeout} s (exit code {process.returncode})")


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs /proc to see what the command has loaded")
@pytest.mark.parametrize("library", ["_multiarray_umath", "libtorch"])
def test_ctrl_c_while_the_command_loads_is_one_line_and_exit_130(tmp_path, library):
    """SIGINT once the process loads numpy (then torch): under the start-up guard, or, on a fast machine,
    the command's own; either way one line and 130. Waiting on what it has loaded, not on a clock."""
    command = [sys.executable, "-m", "vprsnn_export", "train", "--data", "synthetic:8", "--reference", "summer"]
    process = subprocess.Popen(
        [*command, "--quiet", "--epochs", "100000", "--out", str(tmp_path / "net.npz")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as a foreground process gets it
    )
    try:
        wait_for_library(process, library)
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=120)
    finally:
        process.kill()
    assert process.returncode == 130, err
    assert err == "error: interrupted\n"
    assert list(tmp_path.iterdir()) == []
