"""Atomic writes and the npz+JSON container used by checkpoints and fixed-point models.

A container is an ``.npz`` (never pickled) of named numeric arrays plus one ``__meta__`` entry, the UTF-8 bytes
of a JSON header. A file is written to a temporary name in its folder, flushed to disk, then renamed: an
interrupted run never leaves a half-written file under the final name.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import shutil
import stat
import tempfile
import tokenize
import zipfile
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..arguments import require_path
from ..errors import InvalidValueError, ModelFileError, VprError


class OutputError(VprError):
    """An output path that cannot or must not be written (a folder, a device, a link, no permission)."""


META_KEY = "__meta__"


@contextlib.contextmanager
def _writing(path: str | Path) -> Iterator[None]:
    """Turn an OSError of the ``with`` block into one OutputError naming ``path`` ("cannot write here")."""
    try:
        yield
    except OSError as exc:
        raise OutputError(f"cannot write here ({exc.strerror or exc})", path) from None


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    return atomic_write(path, lambda handle: handle.write(data))


def check_output(path: str | Path, *, overwrite: bool = True, inputs: tuple[str | Path | None, ...] = ()) -> Path:
    """The output file ``path`` if it may be written: OutputError when it is empty, a folder, a device or
    other special file, a symbolic link, one of the command's ``inputs``, a name too long for the file
    system, under a file, or (``overwrite=False``) an existing file."""
    path = _not_a_link(path, "file")
    with _writing(path):
        if path.exists():
            mode = path.stat().st_mode
            for refused, reason in (
                (stat.S_ISDIR(mode), "is a folder: give a file name"),
                (not stat.S_ISREG(mode), "is not a regular file (a device, pipe or socket): refusing to replace it"),
                (
                    any(source and Path(source).exists() and path.samefile(source) for source in inputs),
                    "is one of this command's input files: give another output name",
                ),
                (not overwrite, "exists already: give another name, or --force to replace it"),
            ):
                if refused:
                    raise OutputError(reason, path)
        _check_ancestors(path)
    return path


def check_output_folder(path: str | Path) -> Path:
    """The output folder ``path`` if it may be created or written into: OutputError when it is empty, a
    symbolic link, an existing file or special file, under a file, or a name too long for the file system."""
    path = _not_a_link(path, "folder")
    with _writing(path):
        if path.exists() and not path.is_dir():
            raise OutputError("is not a folder: give a new or existing folder", path)
        _check_ancestors(path)
        if path.is_dir():
            tempfile.TemporaryFile(dir=path).close()  # writable, whatever os.access says for root
    return path


def _not_a_link(path: str | Path, what: str) -> Path:
    """``path`` as a Path; OutputError when it is empty or a symbolic link (the ``what``: file or folder)."""
    if str(path).strip() == "":
        raise OutputError("empty output path")
    with _writing(path):
        if Path(path).is_symlink():
            raise OutputError(f"is a symbolic link: give the path of the {what} itself", path)
    return Path(path)


def _check_ancestors(path: Path) -> None:
    """OutputError when the nearest existing ancestor of ``path`` is not a folder or the name is too long for it."""
    parent = next((p for p in path.absolute().parents if p.exists()), Path("/"))
    if not parent.is_dir():
        raise OutputError(f"{parent} is not a folder", path)
    if len(os.fsencode(path.name)) > os.pathconf(parent, "PC_NAME_MAX"):
        raise OutputError("the file name is too long for this file system", path)


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


def atomic_write(path: str | Path, write: Callable[[Any], Any]) -> Path:
    """Call ``write(binary_handle)`` on a temp file next to ``path``, then rename it into place, with the
    permissions a plain ``open`` gives (0666 less the umask); the temp file is removed on any failure or
    interrupt; an unwritable place is one OutputError."""
    path = check_output(path)
    with _writing(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as handle:
                write(handle)
                handle.flush()
                os.fsync(handle.fileno())
            os.chmod(tmp_name, 0o666 & ~_umask())
            os.replace(tmp_name, path)
        except BaseException:
            if os.path.exists(tmp_name):
                os.unlink(tmp_name)
            raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


@contextlib.contextmanager
def output_lock(path: str | Path | None) -> Iterator[None]:
    """Hold an exclusive lock on the output ``path`` (a file or a folder) for the whole ``with`` block.

    The lock is an ``flock`` on a hidden file beside the output, ``.NAME.lock`` (in the nearest existing folder
    above it when its folder does not exist yet), released by the kernel when the process dies: a killed run
    never blocks the next one, and a second writer to the same output gets one OutputError instead of the last
    one winning. While it is held, the temp files and staging folders a killed run left beside the output
    (``.NAME.*.tmp``, ``.NAME.staging-*``, ``.NAME.old-*``: no live writer owns them) are removed, and those
    inside an output folder (``quantize --out DIR``, ``verify --report DIR``) down to :data:`LEFTOVER_DEPTH`
    sub-folders unless another run holds their own output's lock. ``None`` or an empty path: no lock.
    """
    if path is None or str(path).strip() == "":
        yield
        return
    target = Path(path)
    folder = next((p for p in target.absolute().parents if p.is_dir()), Path("/"))  # the nearest existing one
    lock_path = folder / f".{target.name or 'output'}.lock"
    keyed = _keyed_lock(target)  # the same file whichever of the output's folders exist yet
    with contextlib.ExitStack() as descriptors:  # closed last, the keyed one first
        descriptors.callback(os.close, _acquire(lock_path, target))
        keyed.parent.mkdir(mode=0o700, exist_ok=True)
        descriptors.callback(os.close, _acquire(keyed, target))
        if target.parent.is_dir():  # what a killed run left beside the output
            for pattern in (f".{target.name}.*.tmp", f".{target.name}.staging-*", f".{target.name}.old-*"):
                for leftover in target.parent.glob(pattern):
                    _remove(leftover, leftover.is_dir() and not leftover.is_symlink())
        if target.is_dir() and not target.is_symlink():
            _remove_leftovers_inside(target, LEFTOVER_DEPTH)
        try:
            yield
        finally:
            for held in (keyed, lock_path):
                with contextlib.suppress(OSError):
                    os.unlink(held)


def _keyed_lock(target: Path) -> Path:
    """A lock file named by the output's absolute path, in a per-user folder of the temp directory: the folder
    beside the output may not exist yet when one run starts and exist when the next does, so the lock beside it
    alone could differ between two runs writing the same output."""
    key = hashlib.sha256(os.path.abspath(target).encode("utf-8", "surrogateescape")).hexdigest()[:32]
    return Path(tempfile.gettempdir()) / f"vprsnn-export-locks-{os.getuid()}" / f"{key}.lock"


def _acquire(lock_path: Path, target: Path) -> int:
    """An fd holding the flock of ``lock_path``; retried when the file was unlinked by a finishing holder."""
    for _ in range(3):
        with _writing(target):
            fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise OutputError(
                "another vprsnn-export run is writing it now: wait for it or give another output", target
            ) from None
        with contextlib.suppress(FileNotFoundError):
            if os.stat(lock_path).st_ino == os.fstat(fd).st_ino:
                return fd
        os.close(fd)  # the holder unlinked this file as we took it: take the new one
    raise OutputError("could not take the output lock (a run keeps replacing it)", target)


# what atomic_write, staging_folder and publish_folder name their temporaries (mkstemp's 8 random characters)
LEFTOVER_FILE = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}\.tmp$")
LEFTOVER_FOLDER = re.compile(r"^\.(?P<name>.+)\.(?:staging|old)-[a-z0-9_]{8}$")
LEFTOVER_DEPTH = 2  # the deepest a command writes inside its output folder (verify: exports/<network>/)


def _remove_leftovers_inside(folder: Path, depth: int) -> None:
    """Temp files and staging folders a killed run left inside the output ``folder`` (lock held), down to
    ``depth`` sub-folders (links not followed); one whose own output is locked now by another run stays."""
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        is_dir = entry.is_dir(follow_symlinks=False)
        match = (LEFTOVER_FOLDER if is_dir else LEFTOVER_FILE).match(entry.name)
        if match and not _locked_by_another_run(folder / f".{match['name']}.lock"):
            _remove(Path(entry.path), is_dir)
        elif is_dir and depth > 0:
            _remove_leftovers_inside(Path(entry.path), depth - 1)


def _remove(path: Path, is_dir: bool) -> None:
    """Remove a leftover file or folder (not following links); one another process removed first is gone already."""
    if is_dir:
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _locked_by_another_run(lock_path: Path) -> bool:
    """Whether the output lock ``lock_path`` exists and another run holds it (e.g. ``train --out DIR/net.npz``)."""
    try:
        fd = os.open(lock_path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


def staging_folder(out: Path) -> Path:
    """A new hidden folder beside ``out`` (same file system) to build its content in before :func:`publish_folder`."""
    with _writing(out):
        out.absolute().parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{out.name}.staging-", dir=out.absolute().parent))


def publish_folder(staging: Path, out: Path) -> Path:
    """Put the finished folder ``staging`` in place of ``out`` as a whole: one atomic rename, or with an existing
    ``out`` that renamed aside (``.NAME.old-*``), the new one renamed into place and the old one removed (a reader
    sees the old folder, then briefly none, then the new one, never a mix of the two)."""
    out = Path(out)
    os.chmod(staging, 0o777 & ~_umask())
    with _writing(out):
        if out.exists():
            aside = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.absolute().parent))
            os.replace(out, aside / out.name)
            os.replace(staging, out)
            shutil.rmtree(aside, ignore_errors=True)
        else:
            os.replace(staging, out)
    return out


JSON_MAX_BYTES = 256 << 20  # a header, option or report.json larger than this is refused before parsing
JSON_MAX_DEPTH = 64  # nesting of objects and lists (the files written here nest at most 6 deep)
JSON_MAX_DIGITS = 40  # digits of an integer literal (the counts written here have at most 20)


def parse_json(text: str | bytes, what: str) -> Any:
    """JSON parsed within limits of size (:data:`JSON_MAX_BYTES`), nesting (:data:`JSON_MAX_DEPTH`) and integer
    length (:data:`JSON_MAX_DIGITS`), InvalidValueError naming ``what`` beyond them: the one JSON reader for every
    header, option and report. Malformed JSON raises ``json.JSONDecodeError`` (bytes that are not UTF-8:
    ``UnicodeDecodeError``), which callers turn into their own error."""
    if len(text) > JSON_MAX_BYTES:
        raise InvalidValueError(f"{what}: {len(text)} bytes of JSON exceed the limit of {JSON_MAX_BYTES}")
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    try:
        value = json.loads(text, parse_int=lambda literal: _json_int(literal, what))
        stack: list[tuple[Any, int]] = [(value, 1)]
        while stack:
            item, depth = stack.pop()
            if isinstance(item, dict | list):
                if depth > JSON_MAX_DEPTH:
                    break
                stack += [(child, depth + 1) for child in (item.values() if isinstance(item, dict) else item)]
        else:  # no object or list nested deeper than the limit
            return value
    except RecursionError:  # nested deeper than the parser itself goes
        pass
    raise InvalidValueError(f"{what}: JSON nested deeper than {JSON_MAX_DEPTH} levels")


def _json_int(literal: str, what: str) -> int:
    if len(literal.lstrip("-")) > JSON_MAX_DIGITS:
        raise InvalidValueError(f"{what}: JSON integer of {len(literal)} digits exceeds the limit of {JSON_MAX_DIGITS}")
    return int(literal)


def write_container(path: str | Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    """Write arrays plus a JSON header into one ``.npz`` atomically (the savers checked the path and name the
    arrays, never :data:`META_KEY`)."""
    header = np.frombuffer(json.dumps(meta, sort_keys=True).encode("utf-8"), dtype=np.uint8)
    members: dict[str, Any] = {META_KEY: header, **arrays}
    return atomic_write(path, lambda handle: np.savez_compressed(handle, **members))


def is_readable_file(path: str | Path) -> bool:
    """``Path.is_file`` that answers False instead of raising for a name too long or a path through a file."""
    try:
        return Path(path).is_file()
    except OSError:
        return False


#: What reading a truncated or corrupt .npz raises (zipfile: corrupt flags read as "encrypted"/"patched data" and
#: NotImplementedError/RuntimeError; numpy: a corrupt .npy header as SyntaxError or a tokenize error).
_CORRUPT: tuple[type[Exception], ...] = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError)
_CORRUPT += (TypeError, NotImplementedError, RuntimeError, SyntaxError, tokenize.TokenError)


def read_container(path: str | Path, kind: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read a container written by :func:`write_container`; any defect is a ModelFileError naming the file."""
    require_path("path", path)
    if not str(path).strip():
        raise ModelFileError(f"empty {kind} path")
    path = Path(path)
    if not is_readable_file(path):
        raise ModelFileError(f"no such {kind} file" + (" (a folder)" if path.is_dir() else ""), path)
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise ModelFileError(f"not a {kind}: a single .npy array, not an .npz container", path)
        with loaded as npz:
            arrays = {name: npz[name] for name in npz.files}
        foreign = sorted(name for name, value in arrays.items() if not isinstance(value, np.ndarray))
        if foreign:
            raise ModelFileError(f"not a {kind}: members {foreign} are not .npy arrays", path)
    except _CORRUPT as exc:
        raise ModelFileError(f"not a readable {kind} (truncated or corrupt: {exc})", path) from None
    if META_KEY not in arrays:
        raise ModelFileError(f"not a {kind}: the JSON header is missing", path)
    try:
        meta = parse_json(arrays.pop(META_KEY).tobytes(), "header")
    except (UnicodeDecodeError, json.JSONDecodeError, InvalidValueError) as exc:
        raise ModelFileError(f"the JSON header of this {kind} is corrupt ({exc})", path) from None
    if not isinstance(meta, dict):
        raise ModelFileError(f"the JSON header of this {kind} is a {type(meta).__name__}, not a mapping", path)
    return meta, arrays


def sha256_file(path: str | Path) -> str:
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
