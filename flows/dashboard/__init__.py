"""The evaluation dashboard: one self-contained HTML page built from a run's parquet tables only.

``build_dashboard(roots, out)`` reads the score report tables of one or more run stores
(:data:`flows.report.tables.REPORT_TABLES` and the score stage's ``frame_metrics``, through the
run store) and writes a page
that works offline: inline CSS, inline SVG charts, a few lines of vanilla JS, pictures as data
URIs. Pieces: :mod:`.data` (tables), :mod:`.fmt` (number formatting), :mod:`.svg` (charts),
:mod:`.sections` (the page's parts), :mod:`.page` (assembly).
"""

from .page import build_dashboard, render_dashboard

__all__ = ["build_dashboard", "render_dashboard"]
