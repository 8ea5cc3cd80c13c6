"""One root URI (a local path or ``s3://bucket/prefix``) and the few atomic operations the store needs.

Atomicity, per backend:
    local  a write goes to a hidden temporary file in the same folder and ``os.replace`` puts it in
           place (atomic on POSIX); exclusive create is ``O_CREAT | O_EXCL``.
    S3     a single PUT is atomic: readers see the old object or the new one, never a part. Exclusive
           create is a conditional PUT (``If-None-Match: *``). A rename is a server-side copy then a
           delete: the destination appears whole at once, so a temporary key that a reader ignores
           (its name starts with ``.`` and does not end in ``.parquet``) may be left behind by a kill
           between the two calls, never a half-written result.
"""

from __future__ import annotations

import json
import os
import posixpath
import uuid
from pathlib import Path
from typing import Any

import fsspec

from storage.errors import NotAFolderError, StoreError, as_write_error


class RootFS:
    """A store root. Every path argument is relative to the root, with ``/`` separators.

    Args:
        uri: local path or fsspec URL (``s3://bucket/run``).
        storage_options: passed to fsspec (e.g. ``{"endpoint_url": ..., "key": ..., "secret": ...}``).
    """

    def __init__(self, uri: str | Path, storage_options: dict[str, Any] | None = None) -> None:
        self.uri = str(uri)
        self.storage_options = dict(storage_options or {})
        opts = dict(self.storage_options)
        if self.uri.startswith("s3://"):
            opts.setdefault("use_listings_cache", False)  # other writers change listings under us
        self._fs, root = fsspec.core.url_to_fs(self.uri, **opts)
        self.local = _is_local(self._fs)
        self.root = str(Path(root).resolve()) if self.local else root.rstrip("/")
        if self.local:
            self.uri = self.root
        self._checked = self.local

    @property
    def fs(self) -> fsspec.AbstractFileSystem:
        """The filesystem; an S3 root's endpoint and credentials are checked on first use.

        Raises:
            StoreAccessError: the endpoint does not answer, no credentials, a refused key, no bucket.
        """
        if not self._checked:
            self.check()
        return self._fs

    def check(self) -> None:
        """Check that the root can be used, before anything is written: a local root (or a folder
        above it) must not be a file; an S3 root's endpoint must answer with these credentials
        (:func:`storage.remote.check_s3`; asked once per process).

        Raises:
            NotAFolderError: a file stands where the root's folder should be.
            StoreAccessError: the S3 endpoint, credentials or bucket are not usable.
        """
        if self.local:
            blocker = _file_in_the_way(self.root)
            if blocker is not None:
                raise self._not_a_folder(blocker)
            return
        proto = self._fs.protocol[0] if isinstance(self._fs.protocol, tuple) else self._fs.protocol
        if proto in ("s3", "s3a"):
            from storage.remote import check_s3

            check_s3(self.uri, self.root, self.storage_options)
        self._checked = True

    def _not_a_folder(self, blocker: str) -> NotAFolderError:
        if blocker == self.root:
            return NotAFolderError(blocker, "is a file, not a run folder: give a folder (new or a run)")
        return NotAFolderError(blocker, "is a file where the run store needs a folder: the store is damaged")

    def _folder_error(self, exc: OSError, rel: str) -> OSError | NotAFolderError:
        """A NotADirectoryError (or a FileExistsError from makedirs) as the file in the way."""
        blocker = _file_in_the_way(self.path(rel)) if self.local else None
        return exc if blocker is None else self._not_a_folder(blocker)

    # -- paths -------------------------------------------------------------------------------
    def path(self, rel: str) -> str:
        """Absolute path (no protocol) of ``rel`` for the underlying filesystem."""
        return posixpath.join(self.root, rel) if rel else self.root

    def url(self, rel: str) -> str:
        """Full URL of ``rel`` (with protocol for remote stores), for zarr and pyarrow."""
        if self.local:
            return self.path(rel)
        proto = self._fs.protocol[0] if isinstance(self._fs.protocol, tuple) else self._fs.protocol
        return f"{proto}://{self.path(rel)}"

    # -- reads -------------------------------------------------------------------------------
    def read_bytes(self, rel: str) -> bytes | None:
        """The object's bytes, or None when it does not exist."""
        try:
            if self.local:
                return Path(self.path(rel)).read_bytes()
            return self.fs.cat_file(self.path(rel))
        except FileNotFoundError:
            return None
        except NotADirectoryError as exc:
            raise self._folder_error(exc, rel) from None

    def read_json(self, rel: str) -> dict | None:
        data = self.read_bytes(rel)
        if data is None:
            return None
        try:
            return json.loads(data)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:  # a flipped bit may leave bad UTF-8
            raise StoreError(self.url(rel), f"not valid JSON: {exc}") from exc

    def exists(self, rel: str) -> bool:
        if self.local:
            if os.path.exists(self.path(rel)):
                return True
            if os.path.isfile(self.root):  # one stat, only when the answer is no
                raise self._not_a_folder(self.root)
            return False
        return self.fs.exists(self.path(rel))

    def size(self, rel: str) -> int | None:
        """The object's size in bytes, or None when it does not exist."""
        try:
            if self.local:
                return os.stat(self.path(rel)).st_size
            return int(self.fs.info(self.path(rel))["size"])
        except FileNotFoundError:
            return None
        except NotADirectoryError as exc:
            raise self._folder_error(exc, rel) from None

    def sizes(self, rel: str) -> dict[str, int]:
        """Every file under the folder ``rel``, as ``{path relative to rel: size}`` (one walk, or
        one listing on S3); empty when it does not exist."""
        out: dict[str, int] = {}
        if self.local:
            base = self.path(rel)
            if os.path.isfile(self.root):
                raise self._not_a_folder(self.root)
            for folder, _, files in os.walk(base):
                for name in files:
                    path = os.path.join(folder, name)
                    try:
                        out[os.path.relpath(path, base).replace(os.sep, "/")] = os.stat(path).st_size
                    except FileNotFoundError:
                        pass
            return out
        base = self.path(rel).rstrip("/")
        try:
            self.fs.invalidate_cache(base)
            found = self.fs.find(base, detail=True)
        except FileNotFoundError:
            return {}
        for path, info in found.items():
            if info.get("type", "file") == "file":
                out[path[len(base) + 1 :]] = int(info["size"])
        return out

    def listdir(self, rel: str) -> list[str]:
        """Names (not paths) directly under ``rel``; empty when it does not exist."""
        if self.local:
            try:
                return sorted(os.listdir(self.path(rel)))
            except FileNotFoundError:
                return []
            except NotADirectoryError as exc:
                raise self._folder_error(exc, rel) from None
        try:
            self.fs.invalidate_cache(self.path(rel))
            return sorted(posixpath.basename(p.rstrip("/")) for p in self.fs.ls(self.path(rel), detail=False))
        except FileNotFoundError:
            return []

    # -- writes ------------------------------------------------------------------------------
    def write_bytes(self, rel: str, data: bytes) -> None:
        """Write an object atomically (readers see the old or the new content, never a part)."""
        path = self.path(rel)
        if self.local:
            tmp = _tmp_name(path)
            try:
                os.makedirs(os.path.dirname(path), exist_ok=True)
                with open(tmp, "wb") as f:
                    f.write(data)
                os.replace(tmp, path)
            except OSError as exc:  # full, read-only or forbidden: typed, naming the object
                typed = as_write_error(exc, self.url(rel))
                if typed is None:
                    if isinstance(exc, NotADirectoryError | FileExistsError):
                        raise self._folder_error(exc, rel) from None
                    raise
                raise typed from exc
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
        else:
            self.fs.pipe_file(path, data)

    def write_json(self, rel: str, obj: Any, compact: bool = False) -> None:
        """Write ``obj`` as JSON (atomically): indented for files people read, ``compact`` for the
        per-item files of the hot path (an indent makes ``json`` use its pure-Python encoder,
        ~5x slower)."""
        if compact:
            text = json.dumps(obj, sort_keys=True, separators=(",", ":"))
        else:
            text = json.dumps(obj, indent=1, sort_keys=True)
        self.write_bytes(rel, text.encode())

    def create_exclusive(self, rel: str, data: bytes) -> bool:
        """Create ``rel`` only if it does not exist. Returns False when it already exists."""
        path = self.path(rel)
        if self.local:
            try:
                os.makedirs(os.path.dirname(path), exist_ok=True)
            except (NotADirectoryError, FileExistsError) as exc:
                raise self._folder_error(exc, rel) from None
            # write the content under a temporary name first, then hard-link it into place:
            # link() fails if the target exists, and a reader never sees an empty lock file
            tmp = _tmp_name(path)
            with open(tmp, "wb") as f:
                f.write(data)
            try:
                os.link(tmp, path)
                return True
            except FileExistsError:
                return False
            finally:
                os.unlink(tmp)
        try:
            self.fs.pipe_file(path, data, mode="create")
            return True
        except (FileExistsError, OSError) as exc:
            if _is_precondition_failed(exc):
                return False
            raise

    def temp_name(self, rel: str) -> str:
        """A sibling temporary name of ``rel`` that readers ignore (hidden, no ``.parquet`` suffix)."""
        head, tail = posixpath.split(rel)
        return posixpath.join(head, f".{tail}.{uuid.uuid4().hex[:12]}.tmp")

    def rename(self, src: str, dst: str) -> None:
        """Move ``src`` onto ``dst`` (atomic locally; copy-then-delete on S3, see the module doc)."""
        if self.local:
            os.makedirs(os.path.dirname(self.path(dst)), exist_ok=True)
            os.replace(self.path(src), self.path(dst))
        else:
            self.fs.copy(self.path(src), self.path(dst))
            self.fs.rm(self.path(src))

    def remove(self, rel: str, recursive: bool = False) -> None:
        """Delete a file or (with ``recursive``) a folder; missing paths are fine."""
        try:
            if self.local:
                path = self.path(rel)
                if os.path.isdir(path):
                    if recursive:
                        import shutil

                        shutil.rmtree(path)
                else:
                    os.unlink(path)
            else:
                self.fs.rm(self.path(rel), recursive=recursive)
        except FileNotFoundError:
            pass

    def makedirs(self, rel: str) -> None:
        if self.local:
            try:
                os.makedirs(self.path(rel), exist_ok=True)
            except (NotADirectoryError, FileExistsError) as exc:
                raise self._folder_error(exc, rel) from None


def _is_local(fs: fsspec.AbstractFileSystem) -> bool:
    proto = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    return "file" in proto or "local" in proto


def _file_in_the_way(path: str) -> str | None:
    """The first of ``path`` and the folders above it (from the top) that exists and is not a folder."""
    here = Path(path)
    for folder in [*reversed(here.parents), here]:
        if not folder.exists():
            return None
        if not folder.is_dir():
            return str(folder)
    return None


def _tmp_name(path: str) -> str:
    head, tail = os.path.split(path)
    return os.path.join(head, f".{tail}.{uuid.uuid4().hex[:12]}.tmp")


def _is_precondition_failed(exc: BaseException) -> bool:
    if isinstance(exc, FileExistsError):
        return True
    text = f"{exc} {getattr(exc, '__cause__', '')}"
    return "PreconditionFailed" in text or "412" in text
