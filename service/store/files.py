"""Sample arrays on disk: npz files written atomically and verified by SHA-256.

New files hold one uncompressed ``.npy`` member per array, so a member can be memory-mapped or
read a range at a time (``StoredArrays``) without loading the file; files written before that
(``np.savez_compressed``) are still read, their members decompressed as a stream. The checksum
is computed and verified by reading the file in blocks of ``BLOCK_BYTES``, never whole.
"""

from __future__ import annotations

import hashlib
import os
import struct
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np

#: bytes read or written per step (checksums, array members, range reads)
BLOCK_BYTES = 1 << 20
_LOCAL_HEADER = struct.Struct("<4s22xHH")  # signature … file name length, extra field length
_NPY_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


class IntegrityError(RuntimeError):
    """A stored file is missing or its checksum does not match the database."""


def write_arrays(directory: Path, stem: str, arrays: dict[str, np.ndarray]) -> tuple[Path, str]:
    """Write ``arrays`` to ``directory/stem.npz`` atomically (uncompressed members, written in
    blocks); return (path, sha256 hex)."""
    final = directory / f"{stem}.npz"

    def fill(handle: BinaryIO) -> None:
        with zipfile.ZipFile(handle, "w", zipfile.ZIP_STORED, allowZip64=True) as archive:
            for name, values in arrays.items():
                array = np.ascontiguousarray(values)
                if array.dtype.hasobject:
                    raise ValueError(f"array {name!r} holds Python objects; only numbers are stored")
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array_header_1_0(member, np.lib.format.header_data_from_array_1_0(array))
                    data = memoryview(array.reshape(-1)).cast("B")
                    for start in range(0, len(data), BLOCK_BYTES):
                        member.write(data[start : start + BLOCK_BYTES])

    return final, write_atomic(final, fill)


def write_bytes_atomic(final: Path, data: bytes) -> None:
    """Write ``data`` to ``final`` atomically (see ``write_atomic``)."""
    write_atomic(final, lambda handle: handle.write(data))


def write_atomic(final: Path, fill: Callable[[BinaryIO], object]) -> str:
    """Write ``final`` so that a reader (or a restart after kill -9) sees either the old file or the
    whole new one: ``fill`` writes a temporary file in the same directory (named ``.<name>.*.tmp``),
    which is fsync'ed, checksummed, renamed over the final name, and the directory is fsync'ed.
    Returns the file's SHA-256 (hex)."""
    directory = final.parent
    directory.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{final.stem}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w+b") as handle:
            fill(handle)
            handle.flush()
            os.fsync(handle.fileno())
            handle.seek(0)
            digest = _sha256_of(handle)
        os.replace(tmp, final)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(directory)
    return digest


def file_sha256(path: Path) -> str:
    """SHA-256 (hex) of a file, read in blocks; IntegrityError if it is missing."""
    try:
        with open(path, "rb") as handle:
            return _sha256_of(handle)
    except FileNotFoundError:
        raise IntegrityError(f"array file {path} is missing") from None


def verify_file(path: Path, sha256: str) -> None:
    """IntegrityError naming the file unless its SHA-256 is ``sha256``."""
    digest = file_sha256(path)
    if digest != sha256:
        raise IntegrityError(f"array file {path} is corrupt: sha256 {digest} does not match the stored {sha256}")


def read_arrays(path: Path, sha256: str) -> dict[str, np.ndarray]:
    """Every array of an npz file, in memory, after checking its SHA-256."""
    verify_file(path, sha256)
    return load_npz(path)


def load_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of an npz file, in memory (no checksum: the caller verified it)."""
    with np.load(path, allow_pickle=False) as npz:
        return {name: npz[name] for name in npz.files}


def open_arrays(path: Path, sha256: str) -> StoredArrays:
    """The arrays of an npz file, opened lazily (``StoredArrays``) after checking its SHA-256."""
    verify_file(path, sha256)
    return StoredArrays(path)


class StoredArrays:
    """The arrays of one npz file, read on demand: ``names``, ``length`` (samples of a 1-D member),
    ``column(name)`` (memory-mapped when the member is stored uncompressed) and
    ``rows(start, stop, step)`` (copies of a range, read in blocks). Close it (or use ``with``)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self._archive = zipfile.ZipFile(self.path)
        self._handle = open(self.path, "rb")
        self._members: dict[str, dict] = {}
        self._streams: dict[str, BinaryIO] = {}
        for info in self._archive.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with self._archive.open(info) as member:
                read_header = _NPY_HEADERS.get(np.lib.format.read_magic(member))
                if read_header is None:
                    raise IntegrityError(f"array file {path}: {info.filename} has an unknown .npy version")
                shape, fortran, dtype = read_header(member)
                skip = member.tell()
            stored = info.compress_type == zipfile.ZIP_STORED and not fortran
            self._members[info.filename[:-4]] = {
                "info": info,
                "shape": shape,
                "dtype": dtype,
                "skip": skip,
                "offset": self._data_start(info) + skip if stored else None,
            }
        self.names = list(self._members)
        lengths = {m["shape"][0] for m in self._members.values() if len(m["shape"]) == 1}
        self.length = max(lengths) if lengths else 0

    def __enter__(self) -> StoredArrays:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for stream in self._streams.values():
            stream.close()
        self._streams.clear()
        self._handle.close()
        self._archive.close()

    def column(self, name: str) -> np.ndarray:
        """The whole array ``name``: a read-only memory map if stored uncompressed, else loaded."""
        member = self._members[name]
        if member["offset"] is not None and int(np.prod(member["shape"])) > 0:
            return np.memmap(self.path, dtype=member["dtype"], mode="r", offset=member["offset"], shape=member["shape"])
        with self._archive.open(member["info"]) as stream:
            return np.lib.format.read_array(stream, allow_pickle=False)

    def rows(self, start: int, stop: int, step: int = 1, names: list[str] | None = None) -> dict[str, np.ndarray]:
        """Samples ``start:stop:step`` of every (or each named) 1-D array, read ``BLOCK_BYTES`` at a time."""
        stop = min(stop, self.length)
        return {name: self._range(name, start, stop, step) for name in (names or self.names)}

    # ------------------------------------------------------------------ helpers
    def _range(self, name: str, start: int, stop: int, step: int) -> np.ndarray:
        member = self._members[name]
        if len(member["shape"]) != 1:
            return self.column(name)[start:stop:step]
        itemsize = member["dtype"].itemsize
        block = max(step, BLOCK_BYTES // itemsize // step * step)  # whole steps per block
        parts = [self._read(member, name, a, min(a + block, stop))[::step] for a in range(start, stop, block)]
        if len(parts) == 1:
            return parts[0]
        return np.concatenate(parts) if parts else np.empty(0, dtype=member["dtype"])

    def _read(self, member: dict, name: str, start: int, stop: int) -> np.ndarray:
        """Elements ``start:stop`` of a 1-D member, by one positioned read."""
        out = np.empty(max(stop - start, 0), dtype=member["dtype"])
        if member["offset"] is not None:
            stream, position = self._handle, member["offset"]
        else:  # a compressed member: a stream of its own, read forwards (seeking back restarts it)
            stream = self._streams.get(name)
            if stream is None:
                stream = self._streams[name] = self._archive.open(member["info"])
            position = member["skip"]
        stream.seek(position + start * out.itemsize)
        if stream.readinto(memoryview(out).cast("B")) != out.nbytes:
            raise IntegrityError(f"array file {self.path}: {name} is shorter than its header says")
        return out

    def _data_start(self, info: zipfile.ZipInfo) -> int:
        """Offset in the file of a member's first byte (after its local header)."""
        self._handle.seek(info.header_offset)
        signature, name_length, extra_length = _LOCAL_HEADER.unpack(self._handle.read(_LOCAL_HEADER.size))
        if signature != b"PK\x03\x04":
            raise IntegrityError(f"array file {self.path}: bad zip header of {info.filename}")
        return info.header_offset + _LOCAL_HEADER.size + name_length + extra_length


def _sha256_of(handle: BinaryIO) -> str:
    """SHA-256 (hex) of the rest of an open file, read into one reused block."""
    digest, block = hashlib.sha256(), bytearray(BLOCK_BYTES)
    view = memoryview(block)
    while size := handle.readinto(block):
        digest.update(view[:size])
    return digest.hexdigest()


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # some platforms cannot open directories
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
