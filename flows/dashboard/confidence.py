"""The confidence section of any labelled run: the model's confidence per class and per frame, and
pictures of the least confident frames with a class legend.

``data-k`` keys: ``conf:R:CLASS`` (mean winning-class probability of the points the model predicted
as the class), ``lbev:R:RANK`` (a pictured frame's confidence score).
"""

from __future__ import annotations

import base64

from . import fmt, series, svg
from .data import RunTables
from .fmt import cell, esc
from .labelled import totals
from .sections import head, legend, tag

SCORE_COLOUR, SEMANTIC_COLOUR = "#4e79a7", "#f28e2b"


def _png(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode()


def confidence(runs: list[RunTables]) -> str:
    """Per class and per frame confidence; the least confident frames seen from above."""
    parts = [
        '<section id="s-confidence"><h2>Confidence</h2><p class="note">The model\'s winning-class '
        "probability: per class over the points it predicted as that class; per frame the mean over its "
        "points and the frame score (that mean × instance agreement × share of instances of 30 points "
        "or more × stitching IoU), the review export's ranking.</p>"
    ]
    names: list[str] = []
    per_run: list[dict[str, float]] = []
    for r, run in enumerate(runs):
        lab = run.labelled
        n, s = totals(lab, "confidence_points"), {}
        for c in lab.classes:
            s[c["class_id"]] = s.get(c["class_id"], 0.0) + c["confidence_sum"]
        means = {lab.name(c): s[c] / n[c] for c in n if n[c]}
        per_run.append(means)
        names += [k for k in sorted(means, key=lambda k: means[k]) if k not in names]
        parts.append(f"<h3>{tag(r)}{esc(run.label)}</h3>")
        if not means:
            why = (
                "the run has no points"
                if lab.sequences and not any(q["points"] for q in lab.sequences)
                else f"method {esc(lab.run['method'])} stores no per-point probabilities"
            )
            parts.append(f"<p class='note'>{why}: no confidences</p>")
            continue
        body = "".join(
            f"<tr><td>{esc(lab.name(c))}</td>{cell(fmt.count(n[c]), f'confn:{r}:{c}', n[c])}"
            f"{cell(fmt.score(s[c] / n[c]), f'conf:{r}:{c}', s[c] / n[c])}</tr>"
            for c in sorted(n, key=lambda c: s[c] / n[c] if n[c] else 2.0)
            if n[c]
        )
        parts.append(
            f"<table class='num sortable' id='confidence-{r}'>"
            f"{head(('class', 'predicted points', 'confidence %'))}"
            f"<tbody>{body}</tbody></table>"
        )
        for si, (seq, frames) in enumerate(lab.frames.items()):
            scored = [f for f in frames if f["score"] is not None]
            if not scored:
                continue
            chart = series.value_lines(
                [f["index"] for f in scored],
                [("frame score", SCORE_COLOUR, [f["score"] for f in scored]),
                 ("mean winning probability", SEMANTIC_COLOUR, [f["semantic"] for f in scored])],
                1.0, "conf. %", chart_id=f"confidence-{r}-{si}",
            )  # fmt: skip
            parts.append(
                f"<h3>sequence {esc(seq)} · confidence per frame</h3>{chart}<div class='legend'>"
                f"<span class='key'><span class='swatch' style='background:{SCORE_COLOUR}'></span>"
                "frame score</span>"
                f"<span class='key'><span class='swatch' style='background:{SEMANTIC_COLOUR}'></span>"
                "mean winning probability</span></div>"
            )
        parts.append(_gallery(r, run))
    if names and any(per_run):
        bars = svg.hbars(
            names, [[m.get(k) for k in names] for m in per_run], [run.label for run in runs],
            chart_id="bars-confidence",
        )  # fmt: skip
        parts.append(f"<figure><figcaption>confidence per class (%)</figcaption>{bars}</figure>")
    parts.append("</section>")
    return "".join(parts)


def _gallery(r: int, run: RunTables) -> str:
    lab = run.labelled
    if not lab.bev:
        return ""
    figs = "".join(
        f'<figure class="bev" data-k="lbev-fig:{r}:{b["rank"]}">'
        f'<div class="pair"><img alt="classes" src="{_png(b["png_class"])}">'
        f'<img alt="instances" src="{_png(b["png_instance"])}"></div>'
        f"<figcaption>seq {esc(b['sequence'])} · frame {esc(b['frame_id'])} · score "
        f'<b data-k="lbev:{r}:{b["rank"]}" data-v="{esc(repr(b["score"]))}">{fmt.score(b["score"])}</b> %'
        f" · ±{b['extent_m']:.0f} m<br><span class='note'>classes | instances</span></figcaption></figure>"
        for b in lab.bev
    )
    present = sorted(c for c, n in totals(lab, "points").items() if n)
    keys = legend(
        [lab.legend[c] for c in present if c in lab.legend],
        note="instances: one colour per thing instance, stuff in its class colour dimmed",
    )
    return (
        "<h4>least confident frames</h4>"
        "<p class='note'>Seen from above, sensor at the centre, forward up. score: the frame score "
        "in % (mean winning probability × instance agreement × share of instances of 30 points or "
        "more × stitching IoU; 100: sure).</p>"
        f"<div class='gallery'>{figs}</div>{keys}"
    )
