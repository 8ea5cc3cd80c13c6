"""Read a released reference checkpoint file (DS-Net, 4D-DS-Net, Cylinder3D) without unpickling
arbitrary objects; :mod:`dsnet_core.model.reference_convert` converts the state dict it holds.

1. the file must look like what ``torch.save`` writes: its zip archive (``PK\\x03\\x04`` with a
   ``data.pkl``) or its legacy pickle (protocol ≥ 2, first object torch's magic number); anything
   else (a text file, random bytes) is refused as "not a torch checkpoint" before torch reads it;
2. it is read with ``torch.load(weights_only=True)`` only (numpy scalars, which the reference's
   ``other_state`` may hold, are the one addition to torch's allow-list); a file that needs any
   other Python object unpickled is refused, never loaded otherwise;
3. the state dict is the reference's ``model_state`` or the file itself (a bare state dict).

Every refusal is one :class:`CheckpointImportError` line naming the file.
"""

from __future__ import annotations

import pickle
import struct
import zipfile
from pathlib import Path

import numpy as np
import torch

from dsnet_core.errors import CheckpointImportError

#: torch's legacy format starts with a pickled long, torch.serialization.MAGIC_NUMBER; its 10
#: little-endian bytes follow the protocol header and (protocol ≥ 4) a frame length.
_LEGACY_MAGIC = int(torch.serialization.MAGIC_NUMBER).to_bytes(10, "little")
_ZIP_MAGIC = b"PK\x03\x04"
#: what a damaged pickle or archive makes torch.load raise (besides UnpicklingError)
_READ_ERRORS = (RuntimeError, OSError, EOFError, ValueError, KeyError, IndexError, TypeError, struct.error)


def _numpy_scalars() -> list:
    """What the reference's ``other_state`` may hold besides tensors: numpy scalars (best PQ/mIoU)."""
    scalar = np._core.multiarray.scalar
    dtypes = [getattr(np.dtypes, n) for n in ("Float64DType", "Float32DType", "Int64DType", "Int32DType")]
    return [scalar, (scalar, "numpy.core.multiarray.scalar"), np.dtype, *dtypes]


def _one_line(text: str, limit: int = 160) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 1] + "…"


def check_torch_file(src: Path) -> None:
    """Refuse a file that is neither of ``torch.save``'s formats, from its first bytes.

    Raises:
        CheckpointImportError: "not a torch checkpoint: ..." (text, random bytes, a foreign or
            damaged zip archive).
    """
    with open(src, "rb") as f:
        head = f.read(32)
    if head.startswith(_ZIP_MAGIC):
        try:
            with zipfile.ZipFile(src) as archive:
                names = archive.namelist()
        except (zipfile.BadZipFile, OSError) as exc:
            raise CheckpointImportError(
                src, f"not a torch checkpoint: a zip archive that cannot be read (truncated?): {exc}"
            ) from exc
        if not any(n == "data.pkl" or n.endswith("/data.pkl") for n in names):
            raise CheckpointImportError(
                src, "not a torch checkpoint: a zip archive without torch.save's data.pkl"
            )
        return
    if head[:1] == b"\x80" and _LEGACY_MAGIC in head:
        return
    what = "an empty file" if not head else f"the file starts with {head[:12]!r}"
    raise CheckpointImportError(
        src, f"not a torch checkpoint: neither torch.save's zip archive nor its legacy pickle ({what})"
    )


def load_reference_file(src: Path) -> tuple[dict[str, torch.Tensor], dict]:
    """Read a reference checkpoint with ``weights_only=True`` only.

    Args:
        src: the released file.

    Returns:
        (state dict of tensors, info with ``top_level_keys`` and ``epoch`` when present).

    Raises:
        CheckpointImportError: not a torch file, unreadable, needs arbitrary unpickling, or holds no
            state dict.
    """
    if src.is_dir():
        if (src / "card.json").is_file():
            raise CheckpointImportError(
                src,
                "is a folder holding this product's checkpoint (card.json): it needs no import; use it "
                "as it is (dsnet label --checkpoint FOLDER, or train from it with --init-from FOLDER)",
            )
        raise CheckpointImportError(
            src, "is a folder: import-checkpoint reads one released file (*.pth / *.pt); give that file"
        )
    if not src.is_file():
        raise CheckpointImportError(src, "no such file")
    if _is_safetensors(src):
        raise CheckpointImportError(
            src,
            "is a safetensors file, not a torch checkpoint: import-checkpoint reads the reference's "
            "torch *.pth files; this product's own checkpoints are folders (model.safetensors + "
            "card.json): give the folder to dsnet label --checkpoint",
        )
    check_torch_file(src)
    try:
        with torch.serialization.safe_globals(_numpy_scalars()):
            obj = torch.load(src, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        detail = next((ln.strip() for ln in str(exc).splitlines() if "Unsupported global" in ln), "")
        if not detail:
            what = next((ln.strip() for ln in str(exc).splitlines() if "Unsupported" in ln), str(exc))
            raise CheckpointImportError(
                src,
                f"not a readable torch checkpoint: torch.load(weights_only=True) cannot read its pickle "
                f"({_one_line(what)}): damaged, or a pickle protocol it does not support",
            ) from exc
        raise CheckpointImportError(
            src,
            "the file needs unpickling of arbitrary Python objects, which the importer refuses (it "
            f"loads with torch.load(weights_only=True) only; no fallback). {_one_line(detail, 200)} "
            "Re-save only the weights where the file is trusted: "
            "torch.save({'model_state': model.state_dict()}, PATH)",
        ) from exc
    except _READ_ERRORS as exc:
        reason = _one_line(str(exc)) or type(exc).__name__
        raise CheckpointImportError(src, f"not a readable torch checkpoint (truncated?): {reason}") from exc
    return _state_of(obj, src)


def _is_safetensors(src: Path) -> bool:
    """A safetensors file: an 8-byte little-endian header length, then a JSON header ``{...``."""
    with open(src, "rb") as f:
        head = f.read(9)
    if len(head) < 9 or head[8:9] != b"{":
        return src.suffix == ".safetensors"
    return 2 <= int.from_bytes(head[:8], "little") <= src.stat().st_size - 8


def _state_of(obj: object, src: Path) -> tuple[dict[str, torch.Tensor], dict]:
    info: dict = {}
    if isinstance(obj, dict) and "model_state" in obj:
        info = {"top_level_keys": sorted(str(k) for k in obj), "epoch": obj.get("epoch")}
        state = obj["model_state"]
    else:
        state = obj
    if (
        not isinstance(state, dict)
        or not state
        or not all(isinstance(v, torch.Tensor) for v in state.values())
    ):
        raise CheckpointImportError(
            src,
            "holds neither the reference's {'epoch', 'model_state', ...} dict nor a state dict of tensors",
        )
    integer = [
        f"{k} ({str(v.dtype).removeprefix('torch.')})"
        for k, v in state.items()
        if not (v.is_floating_point() or k.endswith("num_batches_tracked"))
    ]
    if integer:
        raise CheckpointImportError(
            src,
            f"{len(integer)} weight(s) are not floating point: {', '.join(integer[:6])}"
            f"{' …' if len(integer) > 6 else ''}; released checkpoints store float32 weights (a file "
            "converted to integers would import truncated values): re-save the float weights",
        )
    if all(k.startswith("module.") for k in state):
        state = {k[len("module.") :]: v for k, v in state.items()}
    if isinstance(info.get("epoch"), torch.Tensor | np.generic):
        info["epoch"] = info["epoch"].item()
    if not isinstance(info.get("epoch"), int | float | None):
        info["epoch"] = None
    return state, info
