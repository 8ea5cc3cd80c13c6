"""Stage manifests and fingerprints: the manifest, not Prefect's cache, decides what is done.

fingerprint = hash(stage, the stage's code version, its config, upstream fingerprints, input digest).
A manifest is written atomically; ``status == "done"`` is written last, after every array, table
and block fragment of the stage.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any, Literal

from pydantic import BaseModel, Field


def fingerprint(
    stage: str, code_version: str, config: dict[str, Any], upstream: dict[str, str], inputs: str
) -> str:
    """A 16-hex-digit digest of everything that determines a stage's output.

    Args:
        stage: stage name.
        code_version: the stage's own version string (bump it when its output changes).
        config: the stage's resolved config (JSON-serialisable).
        upstream: ``{stage: fingerprint}`` of the stages it reads.
        inputs: digest of external inputs (e.g. the source files' sizes and times).
    """
    payload = json.dumps(
        {"stage": stage, "version": code_version, "config": config, "upstream": upstream, "inputs": inputs},
        sort_keys=True,
        separators=(",", ":"),
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


class Manifest(BaseModel):
    """The record of one (sequence, stage).

    ``blocks`` lists the item indices of each block (the unit of work and of resume); a block is
    complete when its fragment with this fingerprint exists. ``tables``: what ``finalize`` wrote
    of each of the stage's tables for this sequence, ``{table: {"path", "size", "blake2b"}}`` (a
    table of the stage without one is damaged: :meth:`storage.run.RunStore.check_stage`).
    """

    stage: str
    sequence: str
    fingerprint: str
    status: Literal["running", "done", "failed"]
    code_version: str
    config: dict[str, Any]
    upstream: dict[str, str]
    inputs: str
    run_id: str
    n_items: int = 0
    blocks: list[list[int]] = Field(default_factory=list)
    plan: dict[str, Any] = Field(default_factory=dict)
    blocks_done: list[int] = Field(default_factory=list)
    counts: dict[str, int] = Field(default_factory=dict)
    timings: dict[str, float] = Field(default_factory=dict)
    started: float = 0.0
    finished: float | None = None
    error: str | None = None
    tables: dict[str, dict[str, Any]] = Field(default_factory=dict)


class BlockFragment(BaseModel):
    """What one block task leaves behind: written after all its items' arrays and ``done`` flags.

    ``records``: each item's record as :meth:`storage.arrays.StageArrays.write_item` returned it
    (``n_points``, and per array the stored chunk's size and digest), by item index, for every item
    the block wrote (not its quarantined ones); empty for table-only stages. A done item without
    one is damaged.

    ``rows`` (the block's table rows) are stored beside the fragment in ``NNNNN.rows``, written
    first, and ``rows_bytes`` is that file's size (0: no rows): the fragment file stays small, so
    reading every fragment of a stage (``dsnet status``, a resume's done blocks) does not parse
    every table row (~70 kB a frame for fusion's instances). The rows are read only when a stage's
    tables are gathered (:meth:`storage.run.RunStore.fragments` with ``rows=True``).
    """

    fingerprint: str
    block: int
    items: list[int]
    seconds: float
    counts: dict[str, int] = Field(default_factory=dict)
    rows: dict[str, list[dict[str, Any]]] = Field(default_factory=dict)
    records: dict[int, dict[str, Any]] = Field(default_factory=dict)
    rows_bytes: int = 0
