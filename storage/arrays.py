"""Padded per-item zarr v3 arrays of one (sequence, stage), one chunk per item, ``done`` flag last.

Layout of the group: for each per-point :class:`~storage.contract.ArraySpec` an array
``(items, max_points, *trailing)`` chunked ``(1, max_points, *trailing)`` (named trailing sizes
resolved from the plan's ``dims`` at creation, and kept in the group's attributes); ``n_points`` int32
``(items,)`` and ``done`` uint8 ``(items,)`` chunked per item. No shards: one writer per chunk,
which is what keeps concurrent block writers correct (sharded writes by several writers corrupt data).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
import zarr
from zarr.codecs import ZstdCodec

from storage.contract import StageContract
from storage.errors import ContractError, StoreError
from storage.fs import RootFS

ZSTD_LEVEL = 3


def _zarr_store(root: RootFS, rel: str, read_only: bool = False):
    if root.local:
        return zarr.storage.LocalStore(root.path(rel), read_only=read_only)
    return zarr.storage.FsspecStore.from_url(
        root.url(rel), storage_options=root.storage_options, read_only=read_only
    )


class StageArrays:
    """The zarr group of one (sequence, stage).

    Args:
        group: an open zarr group.
        contract: the stage's contract (array names and dtypes).
        where: URL for error messages.
    """

    def __init__(self, group: zarr.Group, contract: StageContract, where: str) -> None:
        self.group = group
        self.contract = contract
        self.where = where
        self.names = [s.name for s in contract.arrays if s.name in group.array_keys()]
        self._arrays = {name: group[name] for name in [*self.names, "n_points", "done"]}

    @classmethod
    def create(
        cls,
        root: RootFS,
        rel: str,
        contract: StageContract,
        n_items: int,
        max_points: int,
        omit: Iterable[str] = (),
        dims: Mapping[str, int] | None = None,
    ) -> StageArrays:
        """Create (overwrite) the group with every non-omitted array of the contract.

        Args:
            dims: sizes of the named trailing dimensions (``{"classes": 20}``).
        """
        omit = set(omit)
        bad = {name for name in omit if not contract.array(name).optional}
        if bad:
            raise ContractError(root.url(rel), f"arrays {sorted(bad)} are required by the contract")
        dims = dict(dims or {})
        try:
            trailing = {s.name: s.resolve(dims) for s in contract.arrays if s.name not in omit}
        except KeyError as exc:
            raise ContractError(root.url(rel), str(exc.args[0])) from None
        group = zarr.open_group(_zarr_store(root, rel), mode="w", zarr_format=3)
        group.attrs.update(
            {"stage": contract.stage, "item": contract.item, "max_points": max_points, "dims": dims}
        )
        zstd = ZstdCodec(level=ZSTD_LEVEL)
        for spec in contract.arrays:
            if spec.name in omit:
                continue
            lead = (n_items, max(max_points, 1)) if spec.per_point else (n_items,)
            shape = lead + trailing[spec.name]
            group.create_array(
                spec.name,
                shape=shape,
                chunks=(1, *shape[1:]),
                dtype=spec.dtype,
                compressors=zstd,
                fill_value=0,
                attributes={"doc": spec.doc},
            )
        for name, dtype in (("n_points", "int32"), ("done", "uint8")):
            group.create_array(name, shape=(n_items,), chunks=(1,), dtype=dtype, fill_value=0)
        return cls(group, contract, root.url(rel))

    @classmethod
    def open(cls, root: RootFS, rel: str, contract: StageContract, read_only: bool = True) -> StageArrays:
        try:
            group = zarr.open_group(_zarr_store(root, rel, read_only), mode="r" if read_only else "r+")
        except (FileNotFoundError, zarr.errors.GroupNotFoundError) as exc:
            raise StoreError(root.url(rel), f"no arrays of stage {contract.stage!r}") from exc
        return cls(group, contract, root.url(rel))

    @property
    def n_items(self) -> int:
        return self._arrays["done"].shape[0]

    @property
    def max_points(self) -> int:
        return int(self.group.attrs["max_points"])

    def write_item(self, index: int, values: dict[str, np.ndarray], n_points: int) -> None:
        """Write one item's arrays (valid prefix of ``n_points`` rows), then ``n_points``, then ``done``."""
        missing = set(self.names) - set(values)
        extra = set(values) - set(self.names)
        if missing or extra:
            raise ContractError(
                self.where, f"item {index}: missing arrays {missing or '{}'}, unknown {extra or '{}'}"
            )
        if n_points > self.max_points:
            raise ContractError(
                self.where, f"item {index} has {n_points} points > max_points {self.max_points}"
            )
        for name in self.names:
            spec = self.contract.array(name)
            arr = self._arrays[name]
            value = spec.check(values[name], n_points, arr.shape[2:] if spec.per_point else arr.shape[1:])
            if spec.per_point:
                row = np.zeros(arr.shape[1:], dtype=arr.dtype)
                row[:n_points] = value
                arr[index] = row
            else:
                arr[index] = value
        self._arrays["n_points"][index] = n_points
        self._arrays["done"][index] = 1

    def read_item(self, index: int, names: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """The valid data of one item. Raises StoreError if the item is not done."""
        if not self._arrays["done"][index]:
            raise StoreError(self.where, f"item {index} is not done")
        n = int(self._arrays["n_points"][index])
        out = {}
        for name in self.names if names is None else names:
            spec = self.contract.array(name)
            value = self._arrays[name][index]
            out[name] = value[:n] if spec.per_point else value
        return out

    def done(self) -> np.ndarray:
        """bool ``(items,)``."""
        return self._arrays["done"][:].astype(bool)

    def done_items(self, items) -> np.ndarray:
        """bool flags of the given items (reads only their chunks)."""
        idx = np.asarray(list(items), dtype=np.int64)
        if idx.size == 0:
            return np.zeros(0, bool)
        return self._arrays["done"].get_orthogonal_selection((idx,)).astype(bool)

    def n_points(self) -> np.ndarray:
        return self._arrays["n_points"][:]
