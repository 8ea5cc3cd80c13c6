"""The parts of the dashboard, each a function of the runs' tables returning an HTML fragment.

Every number shown in a table cell carries ``data-k`` (what it is) and ``data-v`` (the table's
value, ``repr``) so a browser test can check the page against the tables.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Sequence

from dsnet_core.metrics.registry import Column, columns

from . import fmt, svg
from .data import RunTables
from .fmt import cell, esc

PRESENT_NOTE = (
    "(present): mean over the classes with ground-truth points in the scope scored; the official "
    "means count every absent class as 0."
)


def headline_columns(runs: list[RunTables]) -> list[Column]:
    """The registered metrics' run-level columns that some run has a value of (registry order)."""
    return [c for c in columns("run") if any(run.run.get(c.key) is not None for run in runs)]


def class_columns() -> list[tuple[str, str]]:
    """``(key, label)`` of the registered per-class fractions (PQ, SQ, RQ, IoU, ...)."""
    return [(c.key, c.label) for c in columns("class") if c.kind == "score"]


def _show(c: Column, v) -> str:
    return fmt.count(v) if c.kind == "count" and v is not None else fmt.score(v)


def tag(i: int) -> str:
    return f'<span class="swatch" style="background:{svg.colour(i)}"></span>'


def head(cols: Sequence[str]) -> str:
    return "<thead><tr>" + "".join(f"<th>{c}</th>" for c in cols) + "</tr></thead>"


def legend(rows: Sequence[dict], dim: bool = False, note: str = "") -> str:
    """A class-colour legend of ``class_legend`` rows (``dim``: stuff in its dimmed colour, as in the
    instance pictures), with an optional note after it."""

    def colour(r: dict) -> str:
        return r["colour_dim"] if dim and r["kind"] != "thing" else r["colour"]

    keys = "".join(
        f'<span class="key" data-class="{esc(r["class"])}"><span class="swatch" style="background:'
        f'{esc(colour(r))}"></span>{esc(r["class"])}</span>'
        for r in rows
    )
    return f'<div class="legend">{keys}{f"<span class=note>{esc(note)}</span>" if note else ""}</div>'


def headline(runs: list[RunTables]) -> str:
    """Cards with the first run's brief numbers, then every registered metric value of every run
    side by side with deltas to A (rows no run has a value of are left out)."""
    a = runs[0].run
    shown = headline_columns(runs)
    cards = "".join(
        f'<div class="card"><div class="big" data-k="card:{c.key}" data-v="{esc(repr(a.get(c.key)))}">'
        f"{_show(c, a.get(c.key))}</div><div>{esc(c.label)}</div></div>"
        for c in shown
        if c.brief
    )
    cols = ["metric"] + [f"{tag(r)}{esc(run.label)}" for r, run in enumerate(runs)]
    cols += [f"Δ {esc(run.label.split(' ')[0])} − A" for run in runs[1:]]
    body = []
    for c in shown:
        key = c.key
        cells = [f'<td title="{esc(c.help)}">{esc(c.label)}</td>']
        cells += [
            cell(_show(c, run.run.get(key)), f"run:{r}:{key}", run.run.get(key)) for r, run in enumerate(runs)
        ]
        for r, run in enumerate(runs[1:], start=1):
            v, base = run.run.get(key), a.get(key)
            diff = None if v is None or base is None else v - base
            text = fmt.delta(v, base) if c.kind == "score" else ("–" if diff is None else f"{diff:+d}")
            cells.append(cell(text, f"delta:{r}:{key}", diff, cls=sign(v, base)))
        body.append("<tr>" + "".join(cells) + "</tr>")
    meta_rows = []
    for key, name, show in (
        ("mode", "scoring mode", str),
        ("model_card", "model card", lambda v: v or "–"),
        ("config_hash", "config hash", str),
        ("run_id", "run id", str),
        ("sequences", "sequences", fmt.count),
        ("frames", "frames", fmt.count),
        ("points", "points", fmt.count),
        ("min_points", "min points", fmt.count),
    ):
        cells = [f"<td>{name}</td>"]
        cells += [cell(show(run.run[key]), f"run:{r}:{key}", run.run[key]) for r, run in enumerate(runs)]
        cells += ["<td></td>"] * (len(runs) - 1)
        meta_rows.append("<tr class='meta'>" + "".join(cells) + "</tr>")
    table = f'<table class="num" id="headline">{head(cols)}<tbody>{"".join(body + meta_rows)}</tbody></table>'
    note = f'<p class="note">{esc(PRESENT_NOTE)}</p>' if any("(present)" in c.label for c in shown) else ""
    return (
        f'<section id="s-headline"><h2>Headline</h2><div class="cards">{cards}</div>{note}{table}</section>'
    )


def sign(v, base) -> str:
    if v is None or base is None or v == base:
        return ""
    return "up" if v > base else "down"


def classes(runs: list[RunTables]) -> str:
    """Per-class PQ/SQ/RQ/IoU tables and bars, things and stuff apart."""
    legend = " ".join(f"{tag(r)}{esc(run.label)}" for r, run in enumerate(runs))
    parts = [f'<section id="s-classes"><h2>Classes</h2><p class="note">{legend}</p>']
    class_cols = class_columns()
    for kind in ("thing", "stuff"):
        names = [c["class"] for c in runs[0].classes if c["kind"] == kind]
        by_run = [{c["class"]: c for c in run.classes} for run in runs]
        cols = ["class"]
        for r in range(len(runs)):
            cols += [f"{tag(r)}{esc(n)}" for _, n in class_cols]
        cols += [f"Δ PQ {run.label.split(' ')[0]}" for run in runs[1:]]
        body = []
        for name in names:
            cells = [f"<td>{esc(name)}</td>"]
            for r, rows in enumerate(by_run):
                c = rows.get(name, {})
                cells += [cell(fmt.score(c.get(k)), f"class:{r}:{name}:{k}", c.get(k)) for k, _ in class_cols]
            base = by_run[0][name]["pq"]
            for r, rows in enumerate(by_run[1:], start=1):
                v = rows.get(name, {}).get("pq")
                cells.append(cell(fmt.delta(v, base), f"cdelta:{r}:{name}", None, cls=sign(v, base)))
            body.append("<tr>" + "".join(cells) + "</tr>")
        series = [run.label for run in runs]
        bars_pq = svg.hbars(
            names,
            [[rows.get(n, {}).get("pq") for n in names] for rows in by_run],
            series,
            chart_id=f"bars-pq-{kind}",
        )
        bars_iou = svg.hbars(
            names,
            [[rows.get(n, {}).get("iou") for n in names] for rows in by_run],
            series,
            chart_id=f"bars-iou-{kind}",
        )
        title = "Things" if kind == "thing" else "Stuff"
        parts.append(
            f"<h3>{title}</h3>"
            f'<table class="num sortable" id="classes-{kind}">{head(cols)}'
            f"<tbody>{''.join(body)}</tbody></table>"
            f'<div class="row"><figure><figcaption>PQ (%)</figcaption>{bars_pq}</figure>'
            f"<figure><figcaption>IoU (%)</figcaption>{bars_iou}</figure></div>"
        )
    parts.append("</section>")
    return "".join(parts)


def sequences(runs: list[RunTables]) -> str:
    """Per-sequence numbers of every run (merged accumulators of the sequence)."""
    keys = [("frames", "frames", fmt.count), ("points", "points", fmt.count)]
    keys += [
        (c.key, c.label, fmt.count if c.kind == "count" else fmt.score) for c in columns("run") if c.brief
    ]
    names = sorted({s["sequence"] for run in runs for s in run.sequences})
    by_run = [{s["sequence"]: s for s in run.sequences} for run in runs]
    cols = ["sequence"] + [f"{tag(r)}{n}" for r in range(len(runs)) for _, n, _ in keys]
    body = []
    for name in names:
        cells = [f"<td>{esc(name)}</td>"]
        for r, rows in enumerate(by_run):
            s = rows.get(name, {})
            cells += [
                cell(show(s.get(k)) if k in s else "–", f"seq:{r}:{name}:{k}", s.get(k))
                for k, _, show in keys
            ]
        body.append("<tr>" + "".join(cells) + "</tr>")
    return (
        '<section id="s-sequences"><h2>Sequences</h2>'
        f'<table class="num sortable" id="sequences">{head(cols)}'
        f"<tbody>{''.join(body)}</tbody></table></section>"
    )


def frames(runs: list[RunTables]) -> str:
    """Per-frame PQ of every run along each sequence, over the point count per frame."""
    parts = [
        '<section id="s-frames"><h2>Frames</h2><p class="note">Lines: per-frame PQ (%, mean over the '
        "classes present in the frame), one colour per run. Grey strip: points per frame. "
        "Hover for values.</p>"
    ]
    names = sorted({s for run in runs for s in run.frames})
    for si, seq in enumerate(names):
        base = next(run.frames[seq] for run in runs if seq in run.frames)
        index = [f["index"] for f in base]
        lines, data = (
            [],
            {
                "index": index,
                "points": [f["n_points"] for f in base],
                "frame_id": [f["frame_id"] for f in base],
                "runs": [],
            },
        )
        for run in runs:
            got = {f["index"]: f for f in run.frames.get(seq, [])}
            pq = [got[i]["pq"] if i in got else None for i in index]
            lines.append((run.label, pq))
            data["runs"].append({"label": run.label, "pq": pq})
        chart = svg.frame_chart(index, lines, data["points"], chart_id=f"frames-{si}")
        payload = json.dumps(data, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
        parts.append(
            f'<h3>sequence {esc(seq)} · {len(index)} frames</h3><div class="framebox" data-seq="{esc(seq)}">'
            f'{chart}<div class="tip"></div><script type="application/json">{payload}</script></div>'
        )
    parts.append("</section>")
    return "".join(parts)


def stage_totals(run: RunTables) -> list[dict]:
    """Timings summed over sequences per stage: items, points, block seconds, rates (per block second)."""
    out: dict[str, dict] = {}
    for t in run.timings:
        s = out.setdefault(
            t["stage"], {"stage": t["stage"], "items": 0, "points": 0, "block_s": 0.0, "wall_s": 0.0}
        )
        s["items"] += t["items"]
        s["points"] += t["points"]
        s["block_s"] += t["block_s"]
        s["wall_s"] += t["wall_s"]
    for s in out.values():
        s["items_per_s"] = s["items"] / s["block_s"] if s["block_s"] > 0 else None
        s["points_per_s"] = s["points"] / s["block_s"] if s["block_s"] > 0 else None
    return list(out.values())


def timings(runs: list[RunTables]) -> str:
    """Stage timings and throughput per run (sums over sequences, from the manifests)."""
    parts = ['<section id="s-timings"><h2>Stage timings and throughput</h2>']
    stages: list[str] = []
    totals = [stage_totals(run) for run in runs]
    for tot in totals:
        stages += [s["stage"] for s in tot if s["stage"] not in stages]
    cols = ("stage", "items", "points", "task s", "wall s", "items/s", "points/s")
    for r, (run, tot) in enumerate(zip(runs, totals, strict=True)):
        body = []
        for s in tot:
            body.append(
                "<tr><td>"
                + esc(s["stage"])
                + "</td>"
                + cell(fmt.count(s["items"]), f"timing:{r}:{s['stage']}:items", s["items"])
                + cell(fmt.count(s["points"]), f"timing:{r}:{s['stage']}:points", s["points"])
                + cell(fmt.seconds(s["block_s"]), f"timing:{r}:{s['stage']}:block_s", s["block_s"])
                + cell(fmt.seconds(s["wall_s"]), f"timing:{r}:{s['stage']}:wall_s", s["wall_s"])
                + cell(fmt.rate(s["items_per_s"]), f"timing:{r}:{s['stage']}:items_per_s", s["items_per_s"])
                + cell(
                    fmt.rate(s["points_per_s"]), f"timing:{r}:{s['stage']}:points_per_s", s["points_per_s"]
                )
                + "</tr>"
            )
        parts.append(
            f"<h3>{tag(r)}{esc(run.label)}</h3><table class='num' id='timings-{r}'>{head(cols)}"
            f"<tbody>{''.join(body)}</tbody></table>"
        )
    secs = [[next((s["block_s"] for s in tot if s["stage"] == st), None) for st in stages] for tot in totals]
    vmax = max([v for row in secs for v in row if v] or [1.0])
    bars = svg.hbars(
        stages, secs, [run.label for run in runs], vmax=vmax, fmt=fmt.seconds, chart_id="bars-timings"
    )
    parts.append(f"<figure><figcaption>task seconds per stage</figcaption>{bars}</figure></section>")
    return "".join(parts)


def _png(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode()


def worst_frames(runs: list[RunTables]) -> str:
    """Bird's-eye views of the worst frames: prediction next to ground truth, coloured by instance."""
    parts = [
        '<section id="s-worst"><h2>Worst frames</h2><p class="note">Seen from above, sensor at the '
        "centre, forward up. Things coloured by instance, stuff by class (dimmed).</p>"
    ]
    for r, run in enumerate(runs):
        figs = []
        for b in run.bev:
            figs.append(
                f'<figure class="bev" data-k="bev:{r}:{b["rank"]}">'
                f'<div class="pair"><img alt="prediction" src="{_png(b["png_pred"])}">'
                f'<img alt="ground truth" src="{_png(b["png_gt"])}"></div>'
                f"<figcaption>seq {esc(b['sequence'])} · frame {esc(b['frame_id'])} · PQ "
                f'<b data-k="bevpq:{r}:{b["rank"]}" data-v="{esc(repr(b["pq"]))}">{fmt.score(b["pq"])}</b>'
                f" · ±{b['extent_m']:.0f} m<br><span class='note'>prediction | ground truth</span>"
                "</figcaption></figure>"
            )
        body = "".join(figs) or "<p class='note'>no pictures in this run</p>"
        parts.append(f"<h3>{tag(r)}{esc(run.label)}</h3><div class='gallery'>{body}</div>")
        truth = run.labelled.legend_truth if run.labelled is not None else {}
        if figs and truth:
            rows = [row for row in truth.values() if row["kind"] == "stuff"]
            parts.append(legend(rows, dim=True, note="things: one colour per instance"))
    parts.append("</section>")
    return "".join(parts)


def review(runs: list[RunTables]) -> str:
    """The least confident instances (fuse instance table / stitch track table), by stage and frame
    numbers."""
    parts = [
        '<section id="s-review"><h2>Review queue</h2><p class="note">Lowest-confidence instances first. '
        "stage: the stage that made the instance; frames: the frame numbers (ingest's index) of the "
        "instance's volume, or the frame a track starts at; confidence: 0–1 (1: sure).</p>"
    ]
    cols = ("#", "stage", "sequence", "frames", "instance", "class", "points", "confidence (0–1)")
    for r, run in enumerate(runs):
        body = []
        for q in run.review:
            k = f"review:{r}:{q['rank']}"
            frames = q.get("frames") or ("–" if q["item"] is None else str(q["item"]))  # older reports
            body.append(
                f"<tr><td>{q['rank'] + 1}</td><td>{esc(q['source'].split('/')[0])}</td>"
                f"<td>{esc(q['sequence'])}</td><td>{esc(frames)}</td>"
                + cell(str(q["instance"]), f"{k}:instance", q["instance"])
                + f"<td>{esc(q['class'])}</td>"
                + cell(fmt.count(q["points"]), f"{k}:points", q["points"])
                + cell(f"{q['confidence']:.3f}", f"{k}:confidence", q["confidence"])
                + "</tr>"
            )
        table = (
            f"<div class='scroll'><table class='num' id='review-{r}'>{head(cols)}"
            f"<tbody>{''.join(body)}</tbody></table></div>"
            if body
            else "<p class='note'>no instance table with confidences in this run</p>"
        )
        parts.append(f"<h3>{tag(r)}{esc(run.label)}</h3>{table}")
    parts.append("</section>")
    return "".join(parts)
