"""A checkpoint folder as a few files small enough to copy back from a GPU machine, and back again.

The device machine returns at most 8 files of at most 16 MiB each, 64 MiB in all. :func:`pack`
writes a checkpoint folder (weights, shifting weights, optimiser state, card, metrics) into
``OUT`` as an uncompressed tar cut into parts of at most 16 MiB (``checkpoint.tar.00``, ...), plus
readable copies of ``card.json`` and ``metrics.csv`` (the validation curve), and last
``checkpoint.json`` — each part's size and sha256 — which makes the set complete. :func:`unpack`
checks the parts against it before extracting, so a copy cut short or mixed from two exports is
refused with the part it found wrong. Only the standard library is used.

The way back is the tighter one: a later run carries ``OUT`` to the next GPU machine together with
the working tree (~24 MiB, 22 of them the bundled models) and the wheels (~12.5 MiB) within the
same 64 MiB. So the optimiser state (Adam's two moments: twice the weights) is packed only while
the whole checkpoint stays within :data:`CARRY_BYTES`; above that it is left out (the manifest
says so) and a resumed run restarts Adam's moments at the epoch it continues — weights, schedule
and the stream's samples continue exactly, the steps after it do not repeat bit for bit.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import tarfile
from pathlib import Path

PART_BYTES = 16 * 2**20
MAX_FILES = 8
MAX_BYTES = 64 * 2**20
MANIFEST = "checkpoint.json"
PART_PREFIX = "checkpoint.tar."
COPIES = ("card.json", "metrics.csv")
CARRY_BYTES = 24 * 2**20
OPTIONAL = ("train_state.safetensors", "train_state.json")
"""Files left out of a checkpoint over :data:`CARRY_BYTES` (the optimiser state)."""


class PartsError(RuntimeError):
    """A checkpoint that does not fit the limits, or parts that do not match their manifest."""


def _tar(folder: Path, names: list[str]) -> bytes:
    """The named files of ``folder`` as an uncompressed tar, in this order."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for name in names:
            info = tar.gettarinfo(str(folder / name), arcname=name)
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            info.mtime = 0
            with open(folder / name, "rb") as f:
                tar.addfile(info, f)
    return buf.getvalue()


def _write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def pack(folder: Path, out: Path, part_bytes: int = PART_BYTES, carry_bytes: int = CARRY_BYTES) -> list[Path]:
    """Write checkpoint ``folder`` into ``out`` as parts, copies and the manifest (written last).

    Hidden files (a staging ``.pending``) are no part of a checkpoint; the optimiser state is
    left out when the checkpoint would exceed ``carry_bytes``.

    Returns:
        The files written, the manifest last.

    Raises:
        PartsError: the files would exceed :data:`MAX_FILES` or :data:`MAX_BYTES`.
    """
    names = sorted(p.name for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    left_out = []
    if sum((folder / n).stat().st_size for n in names) > carry_bytes:
        left_out = [n for n in names if n in OPTIONAL]
        names = [n for n in names if n not in OPTIONAL]
    data = _tar(folder, names)
    parts = [data[i : i + part_bytes] for i in range(0, len(data), part_bytes)] or [b""]
    copies = [c for c in COPIES if (folder / c).is_file()]
    count = len(parts) + len(copies) + 1
    size = len(data) + sum((folder / c).stat().st_size for c in copies)
    if count > MAX_FILES or size > MAX_BYTES:
        raise PartsError(
            f"{folder}: the checkpoint needs {count} files and {size / 2**20:.1f} MiB, over the "
            f"{MAX_FILES} files / {MAX_BYTES / 2**20:.0f} MiB a device run returns: choose a narrower preset"
        )
    out.mkdir(parents=True, exist_ok=True)
    written = []
    records = []
    for i, part in enumerate(parts):
        path = out / f"{PART_PREFIX}{i:02d}"
        _write(path, part)
        written.append(path)
        records.append({"name": path.name, "bytes": len(part), "sha256": hashlib.sha256(part).hexdigest()})
    for stale in out.glob(f"{PART_PREFIX}*"):
        if stale not in written:
            stale.unlink()
    for c in copies:
        _write(out / c, (folder / c).read_bytes())
        written.append(out / c)
    manifest = {"parts": records, "files": names, "tar_sha256": hashlib.sha256(data).hexdigest()}
    if left_out:
        manifest["left_out"] = {"files": left_out, "why": f"over {carry_bytes / 2**20:.0f} MiB to carry back"}
    _write(out / MANIFEST, json.dumps(manifest, indent=2).encode())
    written.append(out / MANIFEST)
    return written


def exists(out: Path) -> bool:
    """Whether ``out`` holds a packed checkpoint (its manifest)."""
    return (out / MANIFEST).is_file()


def unpack(out: Path, dest: Path) -> dict:
    """Check the parts in ``out`` against the manifest and extract the checkpoint into ``dest``.

    Returns:
        The manifest (``files``: the checkpoint's file names; ``left_out``, if any, what was not packed).

    Raises:
        PartsError: no manifest, or a part missing, of another size or another hash.
    """
    if not exists(out):
        raise PartsError(f"{out}: no {MANIFEST}: not a packed checkpoint (or its copy is incomplete)")
    manifest = json.loads((out / MANIFEST).read_text())
    chunks = []
    for rec in manifest["parts"]:
        path = out / rec["name"]
        if not path.is_file():
            raise PartsError(f"{path}: missing; copy every {PART_PREFIX}* file with {MANIFEST}")
        data = path.read_bytes()
        if len(data) != rec["bytes"] or hashlib.sha256(data).hexdigest() != rec["sha256"]:
            raise PartsError(
                f"{path}: {len(data)} bytes that do not match {MANIFEST} ({rec['bytes']} bytes): "
                "a copy cut short or a part of another export"
            )
        chunks.append(data)
    dest.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(b"".join(chunks)), mode="r") as tar:
        tar.extractall(dest, filter="data")
    return manifest
