"""The run report: merged scores, timings, pictures of the worst frames and the review queue,
written as tables beside the run's stage tables (see :mod:`flows.report.merge`)."""

from flows.report.merge import ScoreReport, read_report_table, write_report
from flows.report.tables import HEADLINE_KEYS, REPORT_TABLES

__all__ = ["HEADLINE_KEYS", "REPORT_TABLES", "ScoreReport", "read_report_table", "write_report"]
