"""Assemble the dashboard page from its sections; write it to a file."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from . import sections
from .assets import CSS, JS
from .confidence import confidence
from .data import RunTables, load_run
from .fmt import esc
from .labelled import labelled, tracks
from .refinement import refinement

log = logging.getLogger(__name__)

SCORED = (
    ("s-headline", "Headline", sections.headline),
    ("s-classes", "Classes", sections.classes),
    ("s-sequences", "Sequences", sections.sequences),
    ("s-frames", "Frames", sections.frames),
    ("s-worst", "Worst frames", sections.worst_frames),
)
"""Sections of the runs scored against ground truth."""
LABELLED = (
    ("s-labelled", "Labelled", labelled),
    ("s-confidence", "Confidence", confidence),
    ("s-tracks", "Tracks", tracks),
)
"""Sections of every run with a labelling report (with or without ground truth)."""
REFINED = (("s-refine", "Refinement", refinement),)
"""Sections of runs the refine stage labelled."""
ALL = (
    ("s-timings", "Timings", sections.timings),
    ("s-review", "Review queue", sections.review),
)
"""Sections of every run."""


def page_sections(runs: list[RunTables]) -> list[tuple[str, str, str]]:
    """``(id, name, html)`` of the sections the runs have: scored ones over the scored runs (each
    names the runs it leaves out for want of ground truth), labelling ones over the runs with a
    labelling report, the rest over all."""
    scored = [r for r in runs if r.scored]
    labelled_ = [r for r in runs if r.labelled is not None]
    refined = [r for r in labelled_ if r.labelled.refined]
    out = []
    for group, members in ((SCORED, scored), (LABELLED, labelled_), (REFINED, refined), (ALL, runs)):
        if members:
            out += [(sid, name, fn(members)) for sid, name, fn in group]
    left_out = [r for r in runs if not r.scored]
    if scored and left_out:  # a run without ground truth: said in each scored section
        note = "<p class='warn'>" + "; ".join(
            f"{esc(r.label)} has no ground-truth scores: not in this section" for r in left_out
        ) + "</p>"  # fmt: skip
        sids = {sid for sid, _, _ in SCORED}
        out = [(sid, name, _after_heading(html, note) if sid in sids else html) for sid, name, html in out]
    return out


def _after_heading(html: str, extra: str) -> str:
    """``extra`` inserted after a section's ``<h2>`` heading."""
    at = html.find("</h2>")
    return html if at < 0 else html[: at + 5] + extra + html[at + 5 :]


def in_progress(run: RunTables) -> str:
    """The line that says a run is not finished (``run.progress`` set)."""
    return (
        f"the run is in progress: {run.progress}; the numbers below are of what is done so far "
        "(`dsnet status` shows every stage)"
    )


def render_dashboard(runs: list[RunTables], title: str = "dsnet run report") -> str:
    """The whole page as one HTML string (self-contained: no external requests)."""
    if not runs:
        raise ValueError("render_dashboard needs at least one run")
    parts = page_sections(runs)
    nav = "".join(f'<a href="#{sid}">{name}</a>' for sid, name, _ in parts)
    body = "".join(html for _, _, html in parts)
    roots = " · ".join(f"{esc(r.label)} = {esc(r.root)}" for r in runs)
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    unfinished = "".join(
        f"<p class='warn' data-k='progress:{i}'>{esc(r.label)}: {esc(in_progress(r))}</p>"
        for i, r in enumerate(runs)
        if r.progress
    )
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        "<meta http-equiv='Content-Security-Policy' content=\"default-src 'none'; img-src data:; "
        "style-src 'unsafe-inline'; script-src 'unsafe-inline'\">"
        f"<title>{esc(title)}</title><style>{CSS}</style></head><body>"
        f"<header><h1>{esc(title)}</h1><div class='sub'>{roots} · built {stamp}</div>{unfinished}</header>"
        f"<nav>{nav}</nav><main>{body}</main><script>{JS}</script></body></html>"
    )


def build_dashboard(
    roots: list[str], out: str | Path, title: str = "dsnet run report", storage_options: dict | None = None
) -> Path:
    """Read the report tables of each run root and write the dashboard to ``out``.

    Args:
        roots: run store URIs; the first is the baseline "A" that deltas refer to.
        out: HTML file to write (parent folders are created).

    Returns:
        The written file's path.
    """
    runs = [load_run(root, chr(ord("A") + i), storage_options) for i, root in enumerate(roots)]
    page = render_dashboard(runs, title)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(page, encoding="utf-8")
    tmp.replace(out)
    log.info("dashboard of %d run(s) written to %s", len(runs), out)
    return out
