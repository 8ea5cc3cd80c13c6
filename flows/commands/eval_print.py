"""How ``dsnet eval`` prints scores: every value the metric registry's metrics returned, then per class."""

from __future__ import annotations


def print_scores(
    title: str,
    values: dict[str, float | None],
    classes: dict[str, dict[str, float]],
    hidden: frozenset[str] = frozenset(),
) -> None:
    """One table of every registered run-level value the scorer returned (grouped by metric, each
    with what it is) and one of the per-class values (``hidden``: classes the model cannot name)."""
    from rich.console import Console
    from rich.table import Table

    from dsnet_core.metrics.registry import METRICS

    console = Console(width=max(100, Console().width))
    table = Table(title=title)
    for col, justify in (("metric", "left"), ("value", "right"), ("what it is", "left")):
        table.add_column(col, justify=justify)
    for metric in METRICS.values():
        shown = [c for c in metric.columns if c.key in values]
        for i, c in enumerate(shown):
            table.add_row(c.label, _fmt(c, values[c.key]), c.help, end_section=i == len(shown) - 1)
    console.print(table)
    if any(c.key.endswith("_present") for c in _registered() if c.key in values):
        console.print(
            "(present): mean over the classes with ground-truth points in the frames scored; the official "
            "means count every absent class as 0."
        )
    cols = [c for c in _registered("class") if any(c.key in row for row in classes.values())]
    per = Table(title="per class")
    per.add_column("class")
    for c in cols:
        per.add_column(c.label, justify="right")
    if hidden:
        per.add_column("model can predict", justify="right")
    for name, row in classes.items():
        cells = [_fmt(c, row.get(c.key)) for c in cols]
        per.add_row(name, *cells, *(["no" if name in hidden else "yes"] if hidden else []))
    console.print(per)


def _registered(level: str = "run"):
    from dsnet_core.metrics.registry import columns

    return columns(level)


def _fmt(c, x) -> str:
    if x is None or x != x:
        return "n/a"
    return str(int(x)) if c.kind == "count" else f"{100 * x:.1f}"
