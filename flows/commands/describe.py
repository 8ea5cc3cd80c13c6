"""``dsnet describe``: check every file of a log and print its size and class histogram."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import (
    FIXED_FRAME_HELP,
    FORMAT_HELP,
    READER_OPTION_HELP,
    TOPIC_HELP,
    check_output,
    errors_exit,
)


def describe(
    data: Path = typer.Argument(..., help="Log root (any format `dsnet label` reads)."),
    sequences: str = typer.Option(None, help="Comma-separated sequence names (default: all)."),
    format: str = typer.Option("auto", "--format", help=FORMAT_HELP),
    reader_option: list[str] = typer.Option(None, "--reader-option", help=READER_OPTION_HELP),
    topic: str = typer.Option(None, "--topic", help=TOPIC_HELP),
    fixed_frame: str = typer.Option(None, "--fixed-frame", help=FIXED_FRAME_HELP),
    sensor: bool = typer.Option(
        False,
        "--sensor",
        help="Estimate the LiDAR from the log instead (beams and their elevations, azimuth grid, FOV, "
        "mounting, range limits, ray drop, range noise, remission) and say what could not be estimated.",
    ),
    out: Path = typer.Option(
        None, "--out", help="With --sensor: write the sensor card (YAML) here, for dsnet synth --sensor-card."
    ),
) -> None:
    """Check every file of a log and print its format, per sequence the frames, points per frame,
    sensor fields, intensity convention and pose source, and the class histogram (--sensor: the
    estimated LiDAR instead)."""
    from dsnet_core.io.describe import summarize
    from dsnet_core.io.formats import open_log
    from flows.request import parse_reader_options

    with errors_exit():
        if out is not None and not sensor:
            raise typer.BadParameter("--out writes the sensor card: give it with --sensor")
        if out is not None:
            check_output(out, "--out", "file")
        reader = open_log(
            data, format, parse_reader_options(reader_option, topic=topic, fixed_frame=fixed_frame)
        )
        seqs = sequences.split(",") if sequences else None
        if sensor:
            from dsnet_core.sensor import estimate_sensor

            estimate = estimate_sensor(reader, data, seqs, name=Path(data).name or "sensor")
            if out is not None:
                estimate.card.save(out)
        else:
            summary = summarize(reader, seqs)
    if sensor:
        print_sensor(estimate, out)
        return
    print_log_summary(summary)


def print_sensor(estimate, out: Path | None) -> None:
    """The estimated sensor, and what could not be estimated."""
    import numpy as np

    c = estimate.card
    el = np.asarray(c.elevations_deg)
    spacing = -np.diff(el) if el.size > 1 else np.zeros(1)
    lines = [
        f"sensor estimated from {estimate.frames_used} of {estimate.frames_total} scans of {c.source}",
        f"beams: {c.beams}, elevations {el[0]:+.3f}° … {el[-1]:+.3f}° "
        f"(spacing {spacing.min():.3f}–{spacing.max():.3f}°)",
        "elevations (top first): " + " ".join(f"{v:+.3f}" for v in el),
        f"azimuth: {c.azimuth_steps} firings per turn ({360.0 / c.azimuth_steps:.4f}°), "
        f"scan direction {c.scan_direction or 'unknown'}, horizontal FOV {c.fov_deg:.1f}° "
        f"centred at {c.fov_center_deg:+.1f}°",
        f"sensor centre in the log's frame: ({', '.join(f'{v:+.3f}' for v in c.origin.xyz_m)}) m, "
        f"tilt roll {c.origin.roll_deg:+.2f}° pitch {c.origin.pitch_deg:+.2f}°"
        + ("" if any(c.origin.xyz_m) or c.origin.roll_deg or c.origin.pitch_deg else " (the log's origin)"),
        f"mounting: {c.mount_height_m:.3f} m above the ground, pitch {c.mount_pitch_deg:+.2f}°, "
        f"roll {c.mount_roll_deg:+.2f}° (from the sensor's centre)",
        f"range: {c.min_range_m:.2f}–{c.max_range_m:.1f} m, range noise {100 * c.range_noise_m:.2f} cm, "
        f"{c.returns_per_scan:.0f} returns per scan"
        + (f", a scan every {c.frame_period_s:.3f} s" if c.frame_period_s else ""),
        f"ray drop: {100 * c.ray_drop.rate:.2f} % of the rays that hit a surface; by range "
        + ", ".join(
            f"{a:g}–{b:g} m {100 * r:.1f} %"
            for a, b, r in zip(
                c.ray_drop.range_edges_m, c.ray_drop.range_edges_m[1:], c.ray_drop.by_range, strict=False
            )
        ),
        "ray drop per beam (%): " + " ".join(f"{100 * v:.1f}" for v in c.ray_drop.per_beam),
        "remission quantiles 0/25/50/75/100 %: "
        + " ".join(f"{c.remission.quantiles[k]:.3f}" for k in (0, 5, 10, 15, 20)),
    ]
    for line in lines:
        typer.echo(line)
    if c.not_estimated:
        typer.echo("could not estimate:")
        for key, why in c.not_estimated.items():
            typer.echo(f"  {key}: {why}")
    else:
        typer.echo("could not estimate: nothing")
    if out is not None:
        typer.echo(f"wrote the sensor card to {Path(out).resolve()} (dsnet synth OUT --sensor-card {out})")


def point_limit_lines(summary) -> list[str]:
    """One line per sequence whose largest frame is over `dsnet label`'s default ``--max-points``."""
    from tasks.ingest import MAX_POINTS

    return [
        f"sequence {seq}: frame {frame} has {n} points, over `dsnet label`'s --max-points limit "
        f"({MAX_POINTS}): label refuses it (--max-points N raises the limit, about 1.3 GB of memory "
        "per million points; --on-error skip quarantines such frames)"
        for seq, (frame, n) in summary.largest.items()
        if n > MAX_POINTS
    ]


def print_log_summary(summary) -> None:
    """The sequences table and, for labelled logs, the class histogram."""
    from rich.console import Console
    from rich.table import Table

    console = Console(width=160)
    console.print(f"format: {summary.format}")
    table = Table(title="sequences")
    cols = (
        "sequence",
        "frames",
        "points",
        "points/frame",
        "no return",
        "sensor fields",
        "intensity",
        "poses",
    )
    for col in cols:
        table.add_column(col, justify="right")
    for seq, n in summary.frames.items():
        pts = summary.points[seq]
        source = summary.pose_source.get(seq)
        table.add_row(
            seq,
            str(n),
            str(pts),
            f"{pts / max(n, 1):.0f}",
            str(summary.no_return.get(seq, 0)),
            summary.fields.get(seq, ""),
            summary.intensity.get(seq, ""),
            source or "none (dsnet label --estimate-poses)",
        )
    console.print(table)
    for line in point_limit_lines(summary):
        console.print(line, markup=False, highlight=False)
    if summary.class_points:
        total = sum(summary.class_points.values())
        hist = Table(title="class histogram (train ids)")
        for col in ("class", "points", "share", "instances"):
            hist.add_column(col, justify="right")
        for name, pts in summary.class_points.items():
            inst = summary.class_instances.get(name)
            hist.add_row(
                name, str(pts), f"{100 * pts / max(total, 1):.2f}%", "" if inst is None else str(inst)
            )
        console.print(hist)
