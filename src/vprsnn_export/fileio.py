"""Atomic writes and the npz+JSON container used by checkpoints and fixed-point models.

A container is an ``.npz`` (never pickled) holding named numeric arrays plus one
``__meta__`` entry: the UTF-8 bytes of a JSON header. Files are written to a
temporary name in the destination folder, flushed to disk, then renamed, so an
interrupted run never leaves a half-written file under the final name.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import stat
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ModelFileError, VprError


class OutputError(VprError):
    """An output path that cannot or must not be written (a folder, a device, a link, no permission)."""


META_KEY = "__meta__"


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, fsync, rename)."""
    return atomic_write(path, lambda handle: handle.write(data))


def check_output(path: str | Path, *, overwrite: bool = True) -> Path:
    """The output file ``path`` if it may be written: OutputError when it is empty, a folder, a device or
    other special file, a symbolic link, or (``overwrite=False``) an existing file."""
    if str(path).strip() == "":
        raise OutputError("empty output path")
    path = Path(path)
    if path.is_symlink():
        raise OutputError("is a symbolic link: give the path of the file itself", path)
    if path.exists():
        mode = path.stat().st_mode
        if stat.S_ISDIR(mode):
            raise OutputError("is a folder: give a file name", path)
        if not stat.S_ISREG(mode):
            raise OutputError("is not a regular file (a device, pipe or socket): refusing to replace it", path)
        if not overwrite:
            raise OutputError("exists already: give another name, or --force to replace it", path)
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise OutputError(f"{parent} is not a folder", path)
    return path


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def atomic_write(path: str | Path, write: Callable[[Any], Any]) -> Path:
    """Call ``write(binary_handle)`` on a temp file next to ``path``, then rename it into place.

    The file gets the permissions a plain ``open`` would give (0666 less the umask); the temp
    file is removed on any failure or interrupt; an unwritable place is one OutputError.
    """
    path = check_output(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise OutputError(f"cannot write here ({exc.strerror or exc})", path) from None
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp_name, 0o666 & ~_umask())
        os.replace(tmp_name, path)
    except BaseException as exc:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
        if isinstance(exc, OSError):
            raise OutputError(f"cannot write here ({exc.strerror or exc})", path) from None
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def write_container(path: str | Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    """Write arrays plus a JSON header into one ``.npz`` atomically."""
    if META_KEY in arrays:
        raise ValueError(f"array name {META_KEY!r} is reserved")
    header = np.frombuffer(json.dumps(meta, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    buffer = io.BytesIO()
    members: dict[str, Any] = {META_KEY: header, **arrays}
    np.savez_compressed(buffer, **members)
    return atomic_write_bytes(path, buffer.getvalue())


def read_container(path: str | Path, kind: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read a container written by :func:`write_container`; any defect is a ModelFileError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"no such {kind} file", path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
        raise ModelFileError(f"not a readable {kind} (truncated or corrupt: {exc})", path) from None
    if META_KEY not in arrays:
        raise ModelFileError(f"not a {kind}: the JSON header is missing", path)
    try:
        meta = json.loads(arrays.pop(META_KEY).tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"the JSON header of this {kind} is corrupt ({exc})", path) from None
    if not isinstance(meta, dict):
        raise ModelFileError(f"the JSON header of this {kind} is a {type(meta).__name__}, not a mapping", path)
    return meta, arrays


def sha256_file(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
