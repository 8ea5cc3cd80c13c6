"""``dsnet synth``: synthetic driving logs. Heavy imports stay in the bodies."""

from __future__ import annotations

from pathlib import Path

import typer

from flows.commands.common import check_output, errors_exit


def synth(
    out: Path = typer.Argument(..., help="Log root to write (gets sequences/SS/...)."),
    sequences: int = typer.Option(1, min=1, max=99, help="Number of sequences."),
    frames: int = typer.Option(20, min=1, help="Sweeps per sequence (10 Hz)."),
    seed: int = typer.Option(0, min=0, help="Master seed; each sequence derives its own from it."),
    sensor: str = typer.Option(
        "hdl64",
        help="LiDAR: hdl64 (64 beams), vlp32 (32, faster), nuscenes32 (+10°…−30°), ouster64, ouster128 "
        "(uniform ±22.5°), vlp16, or random (drawn per sequence).",
    ),
    first_sequence: int = typer.Option(0, min=0, max=99, help="Number of the first sequence."),
    overwrite: bool = typer.Option(False, help="Replace sequences that already exist."),
    style: str = typer.Option(
        "classic",
        help="Street: classic, residential, arterial, downtown, junction, parking_lot, country, or random "
        "(drawn per sequence). Anything but classic with hdl64/vlp32 also draws the sensor's mounting, "
        "noise and remission per sequence; each sequence's choices go to synth.json in its folder.",
    ),
    physics: list[str] = typer.Option(
        None,
        help="Altered sensor physics KEY=VALUE, repeatable: elevations=uniform:B:TOP:BOTTOM (or a list of "
        "degrees), azimuth_steps, height, remission_gain, falloff, dropout, far_dropout, range_noise, "
        "min_range, max_range (a LiDAR no preset has; recorded in synth.json).",
    ),
    variety: str = typer.Option(
        "base",
        help="How widely the street styles vary: base, or wide (textured and low buildings, fences of "
        "any height and porosity, bark, people by trees and on grass, rough grass, patchy remission, "
        "flush kerbs, vans as cars). The classic street ignores it.",
    ),
    sensor_card: Path = typer.Option(
        None,
        "--sensor-card",
        help="Render with the LiDAR of this sensor card (YAML, from dsnet describe LOG --sensor --out).",
    ),
    like: Path = typer.Option(
        None,
        "--like",
        help="Render with the LiDAR estimated from this log (as dsnet describe LOG --sensor); the card "
        "is written to OUT/sensor_card.yaml.",
    ),
) -> None:
    """Ray-cast a procedural street with a spinning LiDAR and write it in the SemanticKITTI layout."""
    from dsnet_core.synth.physics import parse_physics

    card = None
    with errors_exit():
        check_output(out, "OUT", "folder")
        altered = parse_physics(physics)
        card = _card(sensor_card, like, sensor, physics)
        generate(
            out, sequences, frames, seed, sensor, first_sequence, overwrite, style, altered, variety, card
        )
        if like is not None:
            card.save(Path(out) / "sensor_card.yaml")
    if card is not None:
        sensor = f"sensor card {card.name}: {card.beams} beams"
    what = sensor if style == "classic" else f"{style} street, {sensor}"
    what += "" if variety == "base" or style == "classic" else f", {variety} variety"
    what += ", altered physics" if physics else ""
    typer.echo(f"wrote {sequences} sequence(s) × {frames} frames ({what}) to {out.resolve() / 'sequences'}")


def generate(
    out: Path,
    sequences: int = 1,
    frames: int = 20,
    seed: int = 0,
    sensor: str = "hdl64",
    first_sequence: int = 0,
    overwrite: bool = False,
    style: str = "classic",
    physics: dict | None = None,
    variety: str = "base",
    sensor_card=None,
) -> list[str]:
    """Write a synthetic log with a progress bar; returns the sequence names.

    Raises:
        DsnetError: bad settings, or sequences that exist without ``overwrite``.
    """
    from rich.progress import Progress

    from dsnet_core.synth import SynthConfig, generate_log

    config = SynthConfig(variety=variety)  # an unknown variety is a ConfigError (one line)

    with Progress(transient=True) as progress:
        task = progress.add_task("ray-casting sweeps", total=sequences * frames)
        return generate_log(
            out,
            sequences=sequences,
            frames=frames,
            seed=seed,
            sensor=sensor,
            first_sequence=first_sequence,
            overwrite=overwrite,
            style=style,
            physics=physics,
            config=config,
            sensor_card=sensor_card,
            on_frame=lambda _seq, _i: progress.advance(task),
        )


def _card(path: Path | None, like: Path | None, sensor: str, physics: list[str] | None):
    """The sensor card of ``--sensor-card`` or ``--like`` (None: neither).

    Raises:
        ConfigError: both given, or either with ``--sensor`` or ``--physics``.
        SensorCardError, SensorEstimateError, DataFormatError: a bad card or log.
    """
    from dsnet_core.errors import ConfigError

    if path is None and like is None:
        return None
    if path is not None and like is not None:
        raise ConfigError("--sensor-card and --like both name the sensor: give one")
    if sensor != "hdl64" or physics:
        raise ConfigError("--sensor-card/--like fix the sensor: leave out --sensor and --physics")
    if path is not None:
        from dsnet_core.sensor import load_card

        return load_card(path)
    from dsnet_core.io.formats import open_log
    from dsnet_core.sensor import estimate_sensor

    return estimate_sensor(open_log(like), like, name=Path(like).resolve().name or "sensor").card
