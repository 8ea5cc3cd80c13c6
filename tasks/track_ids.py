"""Reused instance ids at the stage level (:mod:`dsnet_core.temporal.ids`): the warning a temporal
stage gives once ids are reused, and how readers of final labels tell the hand-outs of an id apart.

A stage's table takes part by declaring the roles ``id``, ``generation`` and ``item`` (the track's
first frame); stages without such a table never reuse ids.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from dsnet_core.temporal.ids import Generations, IdPool
    from storage.run import RunStore
    from tasks.base import Stage

log = logging.getLogger(__name__)

GENERATION_ROLES = ("id", "generation", "item")
"""The roles of a track table that say which hand-out of an id a frame's label means."""


def warn_reuse(sequence: str, stage: str, pool: IdPool, frame: int, warned: bool) -> bool:
    """Log a warning the first time ``pool`` has reused an id; returns whether it was said."""
    if warned or pool.reused == 0:
        return warned
    log.warning(
        "%s %s: the 65535 instance ids of a label are used up (frame %d); ids unused for more than %d "
        "frames are handed out again, the track table's generation tells their tracks apart",
        stage,
        sequence,
        frame,
        pool.reuse_after,
    )
    return True


def track_generations(store: RunStore, sequence: str, stage: Stage) -> Generations:
    """The hand-outs of ids in ``stage``'s final labels, from its first table declaring
    :data:`GENERATION_ROLES` (none: every id means one track)."""
    from dsnet_core.temporal.ids import Generations

    for spec in stage.tables:
        cols = [spec.role(r) for r in GENERATION_ROLES]
        if None in cols:
            continue
        t = store.read_table(sequence, spec).select(cols)
        return Generations(*(t[c].to_numpy(zero_copy_only=False) for c in cols))
    return Generations.none()
