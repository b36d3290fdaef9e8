"""The one way this project writes a file: atomically.

:func:`atomic_write` lets a callback write a temporary file in the target's folder, flushes it
to disk, then renames it over the target, so a reader (or a crash, a kill, a full disk) sees
either the old file or the new one, never half of one. Checkpoints, tables, CSVs, configs and
figures all go through it.
"""

from __future__ import annotations

import csv
import errno
import gzip
import io
import math
import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence


# Errors of writing a file that are the disk's or the user's, not the program's: reported in one
# line naming the file (:func:`write_failure`).
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EACCES, errno.EPERM, errno.EROFS})
_REASONS = {errno.ENOSPC: "no space left on the device", errno.EDQUOT: "the disk quota is exceeded",
            errno.EFBIG: "it would pass this process's file-size limit (ulimit -f)",
            errno.EACCES: "permission denied", errno.EPERM: "permission denied",
            errno.EROFS: "the file system is read-only"}


def shown(origin: str) -> str:
    """A checkpoint's origin as a table names it: a path inside the working directory relative to
    it (``checkpoints/paper_fit/policy3_g/seed0.pt``, not this machine's absolute path), anything
    else (``baseline:policy_ma``, a path elsewhere) as it is."""
    path = Path(origin)
    if not path.is_absolute():
        return origin
    try:
        return path.relative_to(Path.cwd()).as_posix()
    except ValueError:
        return origin


def write_failure(exc: BaseException) -> str | None:
    """``cannot write <file>: <why>`` for an :class:`OSError` of :data:`WRITE_ERRNOS`, else ``None``."""
    if not isinstance(exc, OSError) or exc.errno not in WRITE_ERRNOS:
        return None
    if not exc.filename:  # not a file of this project's (shared memory, a library's temporary file)
        return f"a write failed: {_REASONS[exc.errno]}"
    return f"cannot write {exc.filename}: {_REASONS[exc.errno]}"


def atomic_write(path: str | os.PathLike, write: Callable[[str], None]) -> Path:
    """Call ``write(tmp_path)``, fsync the file, then ``os.replace`` it onto ``path``.

    The temporary file is removed if anything fails; the target is then untouched. An
    :class:`OSError` of :data:`WRITE_ERRNOS` names ``path`` (not the temporary file).
    """
    try:
        return _atomic_write(Path(path), write)
    except OSError as exc:
        if exc.errno in WRITE_ERRNOS and exc.filename != str(path):
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        raise


def _atomic_write(path: Path, write: Callable[[str], None]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the usual mode
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    return atomic_write(path, lambda tmp: Path(tmp).write_bytes(data))


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Text as UTF-8; a ``.gz`` path is gzip-compressed (byte-identical for identical text:
    no timestamp in the header), which ``pandas.read_csv`` and ``gzip.open`` read back."""
    data = text.encode()
    if str(path).endswith(".gz"):
        data = gzip.compress(data, compresslevel=9, mtime=0)
    return write_bytes(path, data)


def csv_value(value: Any) -> Any:
    """How a value is written in this project's CSVs: booleans as 0/1, NaN as empty, floats
    with 6 significant digits."""
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value) if math.isinf(value) else f"{value:.6g}"
    return "" if value is None else value


def csv_text(fieldnames: Sequence[str], rows: Iterable[Mapping[str, Any]]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(fieldnames), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: csv_value(v) for k, v in row.items()})
    return buffer.getvalue()


def write_csv(path: str | os.PathLike, fieldnames: Sequence[str], rows: Iterable[Mapping[str, Any]]) -> Path:
    """Rows of dicts as CSV (missing keys empty, extra keys ignored), written atomically
    (gzip-compressed for a ``.gz`` path)."""
    return write_text(path, csv_text(fieldnames, rows))


def save_torch(obj: Any, path: str | os.PathLike) -> Path:
    """``torch.save`` atomically."""
    import torch

    return atomic_write(path, lambda tmp: torch.save(obj, tmp))


__all__ = ["WRITE_ERRNOS", "atomic_write", "csv_text", "csv_value", "save_torch", "shown", "write_bytes", "write_csv", "write_failure", "write_text"]
