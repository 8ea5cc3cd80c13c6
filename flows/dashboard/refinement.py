"""The refinement section: what the ``refine`` stage changed, and where ground truth exists, the
scores of the labels it read (before) beside those of its labels (after).

``data-k`` keys: ``ref:R:SEQ:KEY`` (``label_sequences``' refine columns), ``before:R:CLASS`` /
``after:R:CLASS`` (class shares over all sequences), ``trans:R:FROM:TO`` (points),
``rs:R:SCOPE:SEQ:CLASS:KEY`` (``refine_scores``).
"""

from __future__ import annotations

from . import fmt, series
from .data import Labelled, RunTables
from .fmt import cell, esc
from .sections import head, sign, tag

TOP_TRANSITIONS = 15
CHANGED_COLOUR = "#e15759"


def refinement(runs: list[RunTables]) -> str:
    """Per run that refined: changes per sequence and frame, class shares and scores before/after."""
    parts = [
        '<section id="s-refine"><h2>Refinement</h2><p class="note">What the refine stage changed in the '
        "temporal stage's labels: points per frame, classes before → after, tracks joined and dissolved. "
        "Where ground truth exists, both label sets are scored by the same scorer.</p>"
    ]
    for r, run in enumerate(runs):
        lab = run.labelled
        parts.append(f"<h3>{tag(r)}{esc(run.label)}</h3>")
        if not lab.refined:
            parts.append("<p class='note'>not refined (label with --refine)</p>")
            continue
        parts += [_sequences(r, lab), _shares(r, lab), _transitions(r, lab), _scores(r, lab)]
        for si, (seq, frames) in enumerate(lab.frames.items()):
            done = [f for f in frames if f["changed"] is not None]
            if not done:
                continue
            share = [f["changed"] / max(f["n_points"], 1) for f in done]
            top = max(max(share), 1e-3)
            chart = series.value_lines(
                [f["index"] for f in done], [("points changed", CHANGED_COLOUR, share)], top * 1.1,
                "changed %", chart_id=f"changed-{r}-{si}",
            )  # fmt: skip
            parts.append(f"<h4>sequence {esc(seq)} · share of points changed per frame</h4>{chart}")
    parts.append("</section>")
    return "".join(parts)


def _sequences(r: int, lab: Labelled) -> str:
    keys = ("changed", "class_changed", "tracks_before", "tracks", "tracks_joined", "tracks_dissolved")
    cols = ("sequence", "points changed", "% of points", "class changed", "tracks before", "tracks after",
            "joined", "dissolved")  # fmt: skip
    body = []
    for s in lab.sequences:
        if not s["refined"]:
            continue
        share = s["changed"] / max(s["points"], 1)
        cells = [cell(fmt.count(s[k]), f"ref:{r}:{s['sequence']}:{k}", s[k]) for k in keys]
        cells.insert(1, cell(fmt.score(share), f"ref:{r}:{s['sequence']}:share", share))
        body.append(f"<tr><td>{esc(s['sequence'])}</td>{''.join(cells)}</tr>")
    return f"<table class='num' id='refine-seq-{r}'>{head(cols)}<tbody>{''.join(body)}</tbody></table>"


def _shares(r: int, lab: Labelled) -> str:
    refined = {s["sequence"] for s in lab.sequences if s["refined"]}
    after: dict[int, int] = {}
    before: dict[int, int] = {}
    for c in lab.classes:
        if c["sequence"] in refined and c["points_before"] is not None:
            after[c["class_id"]] = after.get(c["class_id"], 0) + c["points"]
            before[c["class_id"]] = before.get(c["class_id"], 0) + c["points_before"]
    n_a, n_b = max(sum(after.values()), 1), max(sum(before.values()), 1)
    body = []
    for cid in sorted(after, key=lambda c: -after[c]):
        if not (after[cid] or before[cid]):
            continue
        a, b = after[cid] / n_a, before[cid] / n_b
        colour = lab.legend.get(cid, {}).get("colour", "#888")
        body.append(
            f'<tr><td><span class="swatch" style="background:{esc(colour)}"></span>{esc(lab.name(cid))}</td>'
            + cell(fmt.score(b), f"before:{r}:{cid}", b)
            + cell(fmt.score(a), f"after:{r}:{cid}", a)
            + cell(fmt.delta(a, b), None, cls=sign(a, b))
            + cell(fmt.count(after[cid] - before[cid]), f"gain:{r}:{cid}", after[cid] - before[cid])
            + "</tr>"
        )
    cols = ("class", "share before %", "share after %", "Δ pp", "points gained")
    return (
        f"<h4>class shares before → after</h4><div class='scroll'><table class='num sortable' "
        f"id='refine-shares-{r}'>{head(cols)}<tbody>{''.join(body)}</tbody></table></div>"
    )


def _transitions(r: int, lab: Labelled) -> str:
    sums: dict[tuple[int, int], int] = {}
    for t in lab.transitions:
        key = (t["from_id"], t["to_id"])
        sums[key] = sums.get(key, 0) + t["points"]
    if not sums:
        return "<p class='note'>no class changed</p>"
    total = max(sum(sums.values()), 1)
    top = sorted(sums.items(), key=lambda kv: (-kv[1], kv[0]))[:TOP_TRANSITIONS]
    body = "".join(
        f"<tr><td>{esc(lab.name(a))} → {esc(lab.name(b))}</td>"
        f"{cell(fmt.count(n), f'trans:{r}:{a}:{b}', n)}{cell(fmt.score(n / total))}</tr>"
        for (a, b), n in top
    )
    return (
        f"<h4>largest class changes (of {len(sums)})</h4><table class='num' id='transitions-{r}'>"
        f"{head(('from → to', 'points', '% of class changes'))}<tbody>{body}</tbody></table>"
    )


def _scores(r: int, lab: Labelled) -> str:
    if not lab.refine_scores:
        return "<p class='note'>no ground truth scored: no before/after scores</p>"
    keys = (("pq", "PQ"), ("iou", "mIoU"), ("lstq", "LSTQ"))
    body = []
    for row in [x for x in lab.refine_scores if x["scope"] != "class"]:
        name = "all" if row["scope"] == "run" else f"seq {row['sequence']}"
        cells = []
        for k, _ in keys:
            b, a = row[f"{k}_before"], row[f"{k}_after"]
            base = f"rs:{r}:{row['scope']}:{row['sequence']}::{k}"
            cells += [cell(fmt.score(b), f"{base}_before", b), cell(fmt.score(a), f"{base}_after", a),
                      cell(fmt.delta(a, b), None, cls=sign(a, b))]  # fmt: skip
        body.append(f"<tr><td>{esc(name)}</td>{''.join(cells)}</tr>")
    cols = ["", *(f"{n} {w}" for _, n in keys for w in ("before", "after", "Δ"))]
    out = [f"<h4>scores before → after</h4><table class='num' id='refine-scores-{r}'>{head(cols)}"
           f"<tbody>{''.join(body)}</tbody></table>"]  # fmt: skip
    body = []
    for row in [x for x in lab.refine_scores if x["scope"] == "class"]:
        cells = []
        for k in ("pq", "iou"):
            b, a = row[f"{k}_before"], row[f"{k}_after"]
            base = f"rs:{r}:class::{row['class']}:{k}"
            cells += [cell(fmt.score(b), f"{base}_before", b), cell(fmt.score(a), f"{base}_after", a),
                      cell(fmt.delta(a, b), None, cls=sign(a, b))]  # fmt: skip
        body.append(f"<tr><td>{esc(row['class'])}</td>{''.join(cells)}</tr>")
    cols = ["class", "PQ before", "PQ after", "Δ", "IoU before", "IoU after", "Δ"]
    out.append(
        f"<div class='scroll'><table class='num sortable' id='refine-class-scores-{r}'>{head(cols)}"
        f"<tbody>{''.join(body)}</tbody></table></div>"
    )
    return "".join(out)
