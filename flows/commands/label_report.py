"""What ``dsnet label`` says when it ends: frames labelled, time per stage, the headline scores
where ground truth exists, the dashboard and the next command."""

from __future__ import annotations

from typing import Any


def run_report(
    root: str, summary: list[dict[str, Any]], seconds: float, storage_options: dict | None = None
) -> list[str]:
    """The lines to print after a label run (``summary``: its rows; empty when nothing was pending).

    Args:
        root: the run store.
        summary: one row per (sequence, stage), plus ``failed`` rows.
        seconds: the run's wall time.
    """
    from storage.run import DASHBOARD, RunStore

    store = RunStore(root, storage_options)
    if not summary:
        lines = [f"nothing to do: every stage of every sequence in {root} is done and current "
                 "(--from-stage STAGE or --force recomputes)"]  # fmt: skip
    else:
        ran = [r for r in summary if r.get("action") in ("fresh", "resume", "repair")]
        seqs = sorted({r["sequence"] for r in summary if r.get("action") != "failed"})
        frames = _labelled_frames(store, summary)
        stages: dict[str, float] = {}
        for r in ran:
            stages[r["stage"]] = stages.get(r["stage"], 0.0) + float(r.get("seconds") or 0.0)
        lines = [f"labelled {frames} frames of {len(seqs)} sequence(s) in {seconds:.1f} s"]
        if stages:
            lines.append("  per stage: " + " · ".join(f"{k} {v:.1f} s" for k, v in stages.items()))
        for r in summary:
            if r.get("action") == "failed":
                lines.append(f"  failed: sequence {r['sequence']}: {r.get('error', '')}")
        lines += quarantined_lines(store, seqs)
    lines.append("  " + headline(store))
    if store.root.exists(DASHBOARD):
        lines.append(f"  dashboard: {store.root.url(DASHBOARD)}")
    lines.append(f"  next: dsnet export {root} --out predictions   (dsnet status {root} for every stage)")
    return lines


def headline(store) -> str:
    """``scores (official, 20 frames): PQ 41.5 · mIoU 37.3 · LSTQ 48.1 · mIoU (present) 52.0 · PQ
    (present) 47.9``, or that nothing is scored."""
    from storage.errors import StoreError

    try:
        from flows.report import read_report_table

        run = read_report_table(store, "score_run").to_pylist()[0]
    except (StoreError, FileNotFoundError, IndexError, KeyError):
        return "no ground truth scored (a log without labels, or no score stage)"
    from flows.publish import brief_line

    scores = brief_line({k: v for k, v in run.items() if v is not None})  # the registry's brief numbers
    return f"scores ({run.get('mode', 'official')}, {run.get('frames', '?')} frames): {scores}"


def _labelled_frames(store, summary: list[dict[str, Any]]) -> int:
    """Frames with final labels in this run's sequences (the labels stage's items)."""
    from storage.errors import StoreError
    from tasks.run_config import read_run

    try:
        labels = read_run(store).labels()
    except (StoreError, ValueError):  # a summary line must not fail the run
        return 0
    return sum(int(r.get("items") or 0) for r in summary if r["stage"] == labels)


def quarantined_lines(store, sequences: list[str], shown: int = 5) -> list[str]:
    """What ``--on-error skip`` left out: ``quarantined 1 of 4 frames (no labels): 00/000003: …``,
    the first ``shown`` frames with their reasons (the rest: ``dsnet status`` and the frame table)."""
    from storage.errors import StoreError
    from tasks.ingest import FRAMES

    found: list[tuple[str, str, str]] = []
    total = 0
    for seq in sequences:
        try:
            t = store.read_table(seq, FRAMES).select(["frame_id", "status", "reason"]).to_pydict()
        except (StoreError, KeyError, ValueError):  # a summary line must not fail the run
            continue
        total += len(t["status"])
        found += [
            (seq, f, r or "")
            for f, st, r in zip(t["frame_id"], t["status"], t["reason"], strict=True)
            if st != "ok"
        ]
    if not found:
        return []
    lines = [f"  quarantined {len(found)} of {total} frames (--on-error skip; they have no labels):"]
    for seq, frame, reason in found[:shown]:
        lines.append(f"    {seq}/{frame}: {reason if len(reason) <= 200 else reason[:197] + '...'}")
    if len(found) > shown:
        lines.append(f"    … and {len(found) - shown} more")
    return lines
