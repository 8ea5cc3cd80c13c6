"""The run report: merged scores, timings, pictures of the worst frames and the review queue,
written as tables beside the run's stage tables (see :mod:`flows.report.merge`)."""

from flows.report.merge import ScoreReport, read_report_table, write_report
from flows.report.tables import REPORT_TABLES, headline_keys

__all__ = ["REPORT_TABLES", "ScoreReport", "headline_keys", "read_report_table", "write_report"]
