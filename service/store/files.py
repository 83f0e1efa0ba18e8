"""Sample arrays on disk: compressed npz files written atomically and verified by SHA-256."""
from __future__ import annotations

import hashlib
import io
import os
import tempfile
from pathlib import Path

import numpy as np


class IntegrityError(RuntimeError):
    """A stored file is missing or its checksum does not match the database."""


def write_arrays(directory: Path, stem: str, arrays: dict[str, np.ndarray]) -> tuple[Path, str]:
    """Write ``arrays`` to ``directory/stem.npz`` atomically; return (path, sha256 hex)."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **{k: np.asarray(v) for k, v in arrays.items()})
    data = buffer.getvalue()
    final = directory / f"{stem}.npz"
    write_bytes_atomic(final, data)
    return final, hashlib.sha256(data).hexdigest()


def write_bytes_atomic(final: Path, data: bytes) -> None:
    """Write ``data`` to ``final`` so that a reader (or a restart after kill -9) sees either the
    old file or the whole new one: the bytes go to a temporary file in the same directory (named
    ``.<name>.*.tmp``), are fsync'ed, renamed over the final name, and the directory is fsync'ed."""
    directory = final.parent
    directory.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{final.stem}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, final)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(directory)


def read_arrays(path: Path, sha256: str) -> dict[str, np.ndarray]:
    """Read an npz file after checking its SHA-256; IntegrityError names the file otherwise."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise IntegrityError(f"array file {path} is missing") from None
    digest = hashlib.sha256(data).hexdigest()
    if digest != sha256:
        raise IntegrityError(f"array file {path} is corrupt: sha256 {digest} does not match the "
                             f"stored {sha256}")
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        return {name: npz[name] for name in npz.files}


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # some platforms cannot open directories
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
