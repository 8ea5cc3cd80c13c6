"""A :class:`~flows.request.LabelRequest` from positional test arguments (data, root, sequences,
stages, options), the way most flow tests describe a run."""

from __future__ import annotations

from flows.request import LabelRequest


def req(
    data, root, sequences=None, stages=None, options=None, from_stage=None, force=False, **kw
) -> LabelRequest:
    return LabelRequest(
        data=str(data),
        root=str(root),
        sequences=list(sequences) if sequences is not None else None,
        stages=stages or {},
        options=options or {},
        from_stage=from_stage,
        force=force,
        **kw,
    )
