"""The sections of any labelled run, with or without ground truth: what was labelled and its tracks.

Numbers in table cells carry ``data-k``/``data-v`` like the scored sections
(:mod:`flows.dashboard.sections`): ``lab:R:SEQ:KEY`` (``label_sequences``), ``share:R:SEQ:CLASS``
(a class's share of a sequence's labelled points; SEQ ``*`` for all sequences), ``tracks:R:SEQ:KEY``.
"""

from __future__ import annotations

import statistics
from typing import Any

from . import fmt, series, svg
from .data import Labelled, RunTables
from .fmt import cell, esc
from .sections import head, legend, tag

LENGTHS = ((1, 1), (2, 2), (3, 4), (5, 8), (9, 16), (17, 32), (33, 64), (65, None))
"""Track length buckets, frames (inclusive; None: no upper end)."""


def _cards(items: list[tuple[str, str, str, Any]]) -> str:
    return (
        '<div class="cards">'
        + "".join(
            f'<div class="card"><div class="big" data-k="{esc(k)}" data-v="{esc(repr(v))}">{esc(text)}</div>'
            f"<div>{esc(name)}</div></div>"
            for name, text, k, v in items
        )
        + "</div>"
    )


def class_points(lab: Labelled) -> dict[str, dict[int, dict[str, Any]]]:
    """``label_classes`` rows by sequence and class id."""
    out: dict[str, dict[int, dict[str, Any]]] = {}
    for c in lab.classes:
        out.setdefault(c["sequence"], {})[c["class_id"]] = c
    return out


def totals(lab: Labelled, key: str) -> dict[int, int]:
    """A ``label_classes`` count summed over sequences, by class id."""
    out: dict[int, int] = {}
    for c in lab.classes:
        if c[key] is not None:
            out[c["class_id"]] = out.get(c["class_id"], 0) + c[key]
    return out


def labelled(runs: list[RunTables]) -> str:
    """Frames, points and class shares per sequence, and the shares along each sequence."""
    first = runs[0].labelled
    seqs = first.sequences
    conf_n = sum(s["confidence_points"] for s in seqs)
    conf = sum(s["confidence"] * s["confidence_points"] for s in seqs if s["confidence"] is not None)
    n = {k: sum(s[k] for s in seqs) for k in ("labelled", "points", "tracks")}
    mean = conf / conf_n if conf_n else None
    cards = [
        ("frames labelled", fmt.count(n["labelled"]), "lcard:labelled", n["labelled"]),
        ("points", fmt.count(n["points"]), "lcard:points", n["points"]),
        ("tracks", fmt.count(n["tracks"]), "lcard:tracks", n["tracks"]),
        ("mean confidence %", fmt.score(mean), "lcard:confidence", mean),
    ]
    if first.refined:
        changed = sum(s["changed"] or 0 for s in seqs)
        share = changed / max(sum(s["points"] for s in seqs), 1)
        cards.append(("changed by refine %", fmt.score(share), "lcard:changed", share))
    parts = [
        '<section id="s-labelled"><h2>Labelled</h2><p class="note">What the run labelled, from its final '
        "labels (no ground truth needed). Shares: each class's part of the labelled points.</p>",
        _cards(cards),
    ]
    keys = (
        ("frames", "frames", fmt.count),
        ("labelled", "labelled", fmt.count),
        ("quarantined", "quarantined", fmt.count),
        ("points", "points", fmt.count),
        ("truth_frames", "with ground truth", fmt.count),
        ("tracks", "tracks", fmt.count),
        ("confidence", "confidence %", fmt.score),
    )
    for r, run in enumerate(runs):
        lab = run.labelled
        body = [
            "<tr><td>" + esc(s["sequence"]) + "</td>"
            + "".join(cell(show(s[k]), f"lab:{r}:{s['sequence']}:{k}", s[k]) for k, _, show in keys)
            + f"<td>{'scored' if s['scored'] else 'no'}</td></tr>"
            for s in lab.sequences
        ]  # fmt: skip
        cols = ["sequence", *(n for _, n, _ in keys), "scored"]
        parts.append(
            f"<h3>{tag(r)}{esc(run.label)} · method {esc(lab.run['method'])} · model "
            f"{esc(lab.run['model_card'] or '–')}</h3>"
            f'<table class="num sortable" id="labelled-{r}">{head(cols)}'
            f"<tbody>{''.join(body)}</tbody></table>"
        )
        parts.append(_share_table(r, lab))
        for si, seq in enumerate(lab.frames):
            parts.append(_share_chart(r, si, seq, lab))
    parts.append("</section>")
    return "".join(parts)


def _share_table(r: int, lab: Labelled) -> str:
    by_seq = class_points(lab)
    seqs = [s["sequence"] for s in lab.sequences]
    total = totals(lab, "points")
    n_all = max(sum(total.values()), 1)
    n_seq = {s: max(sum(c["points"] for c in by_seq.get(s, {}).values()), 1) for s in seqs}
    body = []
    for cid in sorted(total, key=lambda c: -total[c]):
        if not total[cid]:
            continue
        row = lab.legend.get(cid, {})
        cells = [f'<td><span class="swatch" style="background:{esc(row.get("colour", "#888"))}"></span>'
                 f"{esc(lab.name(cid))}</td>", cell(row.get("kind", ""))]  # fmt: skip
        cells.append(cell(fmt.score(total[cid] / n_all), f"share:{r}:*:{cid}", total[cid] / n_all))
        for s in seqs:
            v = by_seq.get(s, {}).get(cid, {}).get("points", 0) / n_seq[s]
            cells.append(cell(fmt.score(v), f"share:{r}:{s}:{cid}", v))
        cells.append(cell(fmt.count(total[cid]), f"classpts:{r}:{cid}", total[cid]))
        body.append("<tr>" + "".join(cells) + "</tr>")
    cols = ["class", "kind", "all %", *(f"seq {esc(s)} %" for s in seqs), "points"]
    return (
        f'<div class="scroll"><table class="num sortable" id="shares-{r}">{head(cols)}'
        f"<tbody>{''.join(body)}</tbody></table></div>"
    )


def _share_chart(r: int, si: int, seq: str, lab: Labelled) -> str:
    frames = [f for f in lab.frames[seq] if f["labelled"]]
    if not frames:
        return f"<p class='note'>sequence {esc(seq)}: no labelled frames</p>"
    index = [f["index"] for f in frames]
    n = [max(sum(f["class_points"]), 1) for f in frames]
    present = sorted({c for f in frames for c, p in enumerate(f["class_points"]) if p})
    bands = [
        (lab.name(c), lab.legend.get(c, {}).get("colour", "#888"),
         [f["class_points"][c] / k for f, k in zip(frames, n, strict=True)])
        for c in present
    ]  # fmt: skip
    chart = series.stacked_shares(index, bands, chart_id=f"shares-{r}-{si}")
    return f"<h3>sequence {esc(seq)} · class shares over {len(index)} frames</h3>{chart}" + legend(
        [lab.legend[c] for c in present if c in lab.legend]
    )


def _bucket(n: int) -> int:
    return next(i for i, (lo, hi) in enumerate(LENGTHS) if n >= lo and (hi is None or n <= hi))


def _bucket_name(i: int) -> str:
    lo, hi = LENGTHS[i]
    return f"{lo}" if lo == hi else f"≥ {lo}" if hi is None else f"{lo}–{hi}"


def tracks(runs: list[RunTables]) -> str:
    """Tracks of the final labels: count, lengths, classes."""
    parts = [
        '<section id="s-tracks"><h2>Tracks</h2><p class="note">A track is an instance id of the final '
        "labels; its length is the number of frames it has points in, its class the one of most of its "
        "points.</p>"
    ]
    hist = []
    for r, run in enumerate(runs):
        lab = run.labelled
        by_seq: dict[str, list[dict]] = {}
        for t in lab.tracks:
            by_seq.setdefault(t["sequence"], []).append(t)
        body = []
        for seq in [s["sequence"] for s in lab.sequences]:
            ts = by_seq.get(seq, [])
            lengths = [t["n_frames"] for t in ts]
            vals = {
                "count": len(ts),
                "median": statistics.median(lengths) if lengths else None,
                "longest": max(lengths, default=None),
                "single": sum(n == 1 for n in lengths),
            }
            body.append(
                f"<tr><td>{esc(seq)}</td>"
                + "".join(
                    cell("–" if v is None else f"{v:g}", f"tracks:{r}:{seq}:{k}", v) for k, v in vals.items()
                )
                + "</tr>"
            )
        parts.append(
            f"<h3>{tag(r)}{esc(run.label)}</h3><table class='num' id='tracks-{r}'>"
            f"{head(('sequence', 'tracks', 'median length', 'longest', 'one frame only'))}"
            f"<tbody>{''.join(body)}</tbody></table>"
        )
        counts: dict[int, int] = {}
        for t in lab.tracks:
            counts[t["class_id"]] = counts.get(t["class_id"], 0) + 1
        rows = "".join(
            f"<tr><td>{esc(lab.name(c))}</td>{cell(fmt.count(n), f'trackclass:{r}:{c}', n)}</tr>"
            for c, n in sorted(counts.items(), key=lambda kv: -kv[1])
        )
        parts.append(
            f"<table class='num' id='track-classes-{r}'>{head(('class', 'tracks'))}"
            f"<tbody>{rows}</tbody></table>"
        )
        b = [0] * len(LENGTHS)
        for t in lab.tracks:
            b[_bucket(t["n_frames"])] += 1
        hist.append(b)
    vmax = max([v for row in hist for v in row] or [1])
    bars = svg.hbars(
        [_bucket_name(i) for i in range(len(LENGTHS))], hist, [run.label for run in runs], vmax=vmax,
        fmt=lambda v: f"{v:.0f}", chart_id="bars-track-lengths",
    )  # fmt: skip
    parts.append(f"<figure><figcaption>tracks by length (frames)</figcaption>{bars}</figure></section>")
    return "".join(parts)
