"""Where a lab keeps its sample arrays: a location every service of the lab can read.

``array_url`` (EVCBENCH_ARRAY_URL, ``--array-url``) chooses it:

- empty: ``<data_dir>/arrays`` as always (a single service; no location object, rows hold
  ``arrays/<id>.npz`` relative to the data dir);
- a filesystem path or ``file://`` URL (an NFS mount in a real lab): ``DirectoryArrays``. The
  directory must exist: an unmounted share is refused rather than silently filled on local disk;
- ``s3://bucket/prefix``: ``S3Arrays``, an S3-compatible object store through boto3. The endpoint
  comes from EVCBENCH_S3_ENDPOINT_URL (or AWS_ENDPOINT_URL; none means AWS itself), the
  credentials and region from the usual AWS variables (AWS_ACCESS_KEY_ID, …, AWS_DEFAULT_REGION).
  Reads go through ``<data_dir>/cache/arrays/<sha256>.npz``, verified at every use and trimmed to
  EVCBENCH_ARRAY_CACHE_BYTES (default 4 GB), least recently used first.

A row's ``file`` is then a key relative to the location (``<id>.npz``). Every object is complete
npz bytes whose SHA-256 the row holds; a location never changes an object once written.
A location that cannot be reached raises ``ArrayStoreUnavailable`` (HTTP 503), naming its URL.
"""

from __future__ import annotations

import base64
import hashlib
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote, urlsplit

from service.store.files import BLOCK_BYTES, IntegrityError, file_sha256, write_atomic

#: keys under this prefix of a location hold objects set aside by ``evcbench store repair``
QUARANTINE_PREFIX = "quarantine/"
#: bytes of local copies of S3 objects kept by default (EVCBENCH_ARRAY_CACHE_BYTES)
DEFAULT_CACHE_BYTES = 4e9


class ArrayStoreUnavailable(RuntimeError):
    """The shared array location ``url`` cannot be used now (unreachable, refused, not mounted)."""

    def __init__(self, url: str, reason: str):
        super().__init__(f"array store {url} is unavailable: {reason}")
        self.url, self.reason = url, reason

    def __str__(self) -> str:
        return self.args[0]


def open_location(array_url: str | None, cache_dir: Path) -> DirectoryArrays | S3Arrays | None:
    """The location ``array_url`` names (None for the data dir's own ``arrays/``); ``cache_dir`` holds
    local copies of objects read from S3. ValueError naming ``array_url`` if it is malformed."""
    if not array_url:
        return None
    scheme = urlsplit(array_url).scheme
    if scheme == "s3":
        return S3Arrays(array_url, cache_dir)
    if scheme == "file":
        return DirectoryArrays(Path(unquote(urlsplit(array_url).path)))
    if scheme == "" or len(scheme) == 1:  # a path (or a Windows drive letter)
        return DirectoryArrays(Path(array_url))
    raise ValueError(f"array_url: {array_url!r} is neither a path, a file:// URL nor an s3://bucket/prefix URL")


class DirectoryArrays:
    """Arrays in a shared directory (``root``), written atomically by any service that mounts it."""

    shared = True

    def __init__(self, root: Path):
        self.root = Path(root).absolute()
        self.url = str(self.root)

    def where(self, key: str) -> str:
        """The full location of ``key``, for messages."""
        return str(self.root / key)

    def _mounted(self) -> None:
        if not self.root.is_dir():
            raise ArrayStoreUnavailable(self.url, "the directory does not exist (is the shared volume mounted?)")

    def put(self, local: Path, key: str, sha256: str) -> None:
        """Copy the complete file ``local`` to ``key`` atomically; its SHA-256 must stay ``sha256``."""
        self._mounted()
        try:

            def fill(handle) -> None:
                with open(local, "rb") as source:
                    shutil.copyfileobj(source, handle, BLOCK_BYTES)

            digest = write_atomic(self.root / key, fill)
        except OSError as exc:
            raise ArrayStoreUnavailable(self.url, f"writing {key} failed: {exc}") from exc
        if digest != sha256:
            (self.root / key).unlink(missing_ok=True)
            raise ArrayStoreUnavailable(self.url, f"the copy of {key} does not match its sha256")

    def fetch(self, key: str, sha256: str) -> Path:
        """A local path of ``key``, verified against ``sha256`` (IntegrityError if missing or corrupt)."""
        self._mounted()
        path = self.root / key
        try:
            digest = file_sha256(path)
        except OSError as exc:
            raise ArrayStoreUnavailable(self.url, f"reading {key} failed: {exc}") from exc
        if digest != sha256:
            raise IntegrityError(f"array file {path} is corrupt: sha256 {digest} does not match the stored {sha256}")
        return path

    def size(self, key: str) -> int | None:
        """Bytes of ``key``, None if there is no such file."""
        self._mounted()
        try:
            return (self.root / key).stat().st_size
        except FileNotFoundError:
            return None

    def sha256(self, key: str) -> str:
        """SHA-256 of ``key``'s bytes (IntegrityError if it is missing)."""
        self._mounted()
        return file_sha256(self.root / key)

    def delete(self, key: str) -> None:
        self._mounted()
        (self.root / key).unlink(missing_ok=True)

    def adopt(self, local: Path, sha256: str) -> None:
        """The local copy of an uploaded file is not needed: reads go to the shared directory."""
        Path(local).unlink(missing_ok=True)

    def forget(self, sha256: str) -> None:
        """Nothing is cached for a directory."""

    def move(self, key: str, to: str) -> None:
        """Rename ``key`` to ``to`` (FileExistsError if ``to`` exists)."""
        self._mounted()
        target = self.root / to
        if target.exists():
            raise FileExistsError(f"{self.where(to)} exists")
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(self.root / key, target)

    def keys(self) -> Iterator[tuple[str, int, float]]:
        """(key, bytes, age in seconds) of every finished array file (not temporary, not quarantined)."""
        self._mounted()
        now = time.time()
        for path in sorted(self.root.iterdir()):
            if path.is_file() and path.suffix == ".npz" and not path.name.startswith("."):
                stat = path.stat()
                yield path.name, stat.st_size, now - stat.st_mtime


class S3Arrays:
    """Arrays as objects ``<prefix>/<key>`` of an S3 bucket; reads go through a local cache of verified
    copies named by their SHA-256 (``cache_dir/<sha256>.npz``)."""

    shared = True

    def __init__(self, url: str, cache_dir: Path):
        parts = urlsplit(url)
        if not parts.netloc:
            raise ValueError(f"array_url: {url!r} names no bucket (s3://bucket/prefix)")
        self.url, self.bucket, self.prefix = url.rstrip("/"), parts.netloc, parts.path.strip("/")
        self.endpoint_url = os.environ.get("EVCBENCH_S3_ENDPOINT_URL") or os.environ.get("AWS_ENDPOINT_URL") or None
        self.cache_dir = Path(cache_dir)
        self._client = None

    # ------------------------------------------------------------------ plumbing
    @property
    def client(self):
        """The boto3 client (made on first use; boto3 clients may be shared between threads)."""
        if self._client is None:
            import boto3
            from botocore.config import Config

            config = Config(
                connect_timeout=5,
                read_timeout=60,
                retries={"max_attempts": 3, "mode": "standard"},
                s3={"addressing_style": "path"} if self.endpoint_url else None,
            )
            self._client = boto3.session.Session().client("s3", endpoint_url=self.endpoint_url, config=config)
        return self._client

    def _name(self, key: str) -> str:
        return f"{self.prefix}/{key}" if self.prefix else key

    def where(self, key: str) -> str:
        return f"s3://{self.bucket}/{self._name(key)}"

    def _call(self, what: str, method: str, **kwargs):
        """``client.<method>(Bucket=…, **kwargs)``; ArrayStoreUnavailable for a connection, credential or
        server problem, FileNotFoundError for a missing object."""
        from botocore.exceptions import BotoCoreError, ClientError

        where = f" (endpoint {self.endpoint_url})" if self.endpoint_url else ""
        try:
            return getattr(self.client, method)(Bucket=self.bucket, **kwargs)
        except ClientError as exc:
            error = exc.response.get("Error", {})
            code = str(error.get("Code", ""))
            if code in ("404", "NoSuchKey", "NotFound"):
                raise FileNotFoundError(f"{what}: no such object") from exc
            raise ArrayStoreUnavailable(self.url, f"{what}: {code} {error.get('Message', '')}".strip()) from exc
        except BotoCoreError as exc:
            text = str(exc) if not self.endpoint_url or self.endpoint_url in str(exc) else f"{exc}{where}"
            raise ArrayStoreUnavailable(self.url, f"{what}: {text}") from exc

    # ------------------------------------------------------------------ the location's verbs
    def put(self, local: Path, key: str, sha256: str) -> None:
        """Upload the complete file ``local`` as ``key`` in one PUT (an object appears whole or not at
        all), with its SHA-256 for the server to check; then check what the server received."""
        checksum = base64.b64encode(bytes.fromhex(sha256)).decode()
        md5 = hashlib.md5()
        with open(local, "rb") as handle:
            while block := handle.read(BLOCK_BYTES):
                md5.update(block)
            handle.seek(0)
            answer = self._call(
                f"uploading {key}",
                "put_object",
                Key=self._name(key),
                Body=handle,
                ChecksumSHA256=checksum,
                Metadata={"sha256": sha256},
            )
        received = answer.get("ChecksumSHA256")
        etag = str(answer.get("ETag", "")).strip('"')
        if received is not None:
            good = received == checksum
        elif len(etag) == 32 and "-" not in etag:  # a single PUT without KMS: the ETag is the MD5
            good = etag == md5.hexdigest()
        else:
            good = self.size(key) == Path(local).stat().st_size
        if not good:
            self.delete(key)
            raise ArrayStoreUnavailable(self.url, f"the upload of {key} does not match its checksum")

    def fetch(self, key: str, sha256: str) -> Path:
        """A verified local copy of ``key``: the cached one if its SHA-256 is still ``sha256``, else a fresh
        download (IntegrityError if the object is missing or does not match ``sha256``)."""
        cached = self.cache_dir / f"{sha256}.npz"
        try:
            if file_sha256(cached) == sha256:
                os.utime(cached)  # recently used: trimmed last
                return cached
        except (IntegrityError, FileNotFoundError):
            pass  # not cached (or just trimmed by another thread)
        try:
            body = self._call(f"reading {key}", "get_object", Key=self._name(key))["Body"]
        except FileNotFoundError:
            raise IntegrityError(f"array object {self.where(key)} is missing") from None

        def fill(handle) -> None:
            try:
                for block in body.iter_chunks(BLOCK_BYTES):
                    handle.write(block)
            except Exception as exc:  # the connection broke mid-object
                raise ArrayStoreUnavailable(self.url, f"reading {key} broke off: {exc}") from exc

        digest = write_atomic(cached, fill)
        if digest != sha256:
            cached.unlink(missing_ok=True)
            raise IntegrityError(
                f"array object {self.where(key)} is corrupt: sha256 {digest} does not match the stored {sha256}"
            )
        self.trim_cache(keep=cached)
        return cached

    def trim_cache(self, keep: Path | None = None) -> int:
        """Delete the least recently used cached copies until the cache holds at most
        EVCBENCH_ARRAY_CACHE_BYTES (default 4 GB), never ``keep``; returns the bytes freed. A copy an
        open reader has memory-mapped stays readable to it (the file lives on until it is closed)."""
        limit = float(os.environ.get("EVCBENCH_ARRAY_CACHE_BYTES") or DEFAULT_CACHE_BYTES)
        entries = []
        for path in self.cache_dir.glob("*.npz"):
            try:
                stat = path.stat()
            except FileNotFoundError:
                continue
            entries.append((stat.st_mtime, stat.st_size, path))
        total, freed = sum(size for _, size, _ in entries), 0
        for _, size, path in sorted(entries, key=lambda e: e[0]):
            if total - freed <= limit:
                break
            if path != keep:
                path.unlink(missing_ok=True)
                freed += size
        return freed

    def adopt(self, local: Path, sha256: str) -> None:
        """Keep the just-uploaded file ``local`` as the cached copy of its object (no download to read it)."""
        self.cache_dir.mkdir(parents=True, exist_ok=True)
        os.replace(local, self.cache_dir / f"{sha256}.npz")

    def forget(self, sha256: str) -> None:
        """Drop the cached copy of an object (its dataset was deleted)."""
        (self.cache_dir / f"{sha256}.npz").unlink(missing_ok=True)

    def size(self, key: str) -> int | None:
        try:
            return int(self._call(f"looking up {key}", "head_object", Key=self._name(key))["ContentLength"])
        except FileNotFoundError:
            return None

    def sha256(self, key: str) -> str:
        """SHA-256 of the object's bytes, streamed (IntegrityError if it is missing)."""
        try:
            body = self._call(f"reading {key}", "get_object", Key=self._name(key))["Body"]
        except FileNotFoundError:
            raise IntegrityError(f"array object {self.where(key)} is missing") from None
        digest = hashlib.sha256()
        for block in body.iter_chunks(BLOCK_BYTES):
            digest.update(block)
        return digest.hexdigest()

    def delete(self, key: str) -> None:
        self._call(f"deleting {key}", "delete_object", Key=self._name(key))

    def move(self, key: str, to: str) -> None:
        """Copy ``key`` to ``to`` (FileExistsError if ``to`` exists), then delete ``key``."""
        if self.size(to) is not None:
            raise FileExistsError(f"{self.where(to)} exists")
        self._call(
            f"copying {key}",
            "copy_object",
            Key=self._name(to),
            CopySource={"Bucket": self.bucket, "Key": self._name(key)},
        )
        self.delete(key)

    def keys(self) -> Iterator[tuple[str, int, float]]:
        """(key, bytes, age in seconds) of every object under the prefix (not quarantined)."""
        start = f"{self.prefix}/" if self.prefix else ""
        token, now = None, time.time()
        while True:
            page = self._call(
                "listing objects", "list_objects_v2", Prefix=start, **({"ContinuationToken": token} if token else {})
            )
            for item in page.get("Contents", []):
                key = item["Key"][len(start) :]
                if key.endswith(".npz") and not key.startswith(QUARANTINE_PREFIX):
                    yield key, int(item["Size"]), now - item["LastModified"].timestamp()
            if not page.get("IsTruncated"):
                return
            token = page["NextContinuationToken"]
