"""What ``dsnet adapt`` trains on besides the pseudo-labels: corrected frames (``--labels``) and the
source scans of the mixed pairs (the synthetic stream, or ``--source-log``)."""

from __future__ import annotations

from pathlib import Path

from dsnet_core.adapt import MIN_HELDOUT, AdaptConfig, Item, LabelOverlay, LogSource, StreamSource, volumes
from dsnet_core.adapt.source import Source, stream_probe
from dsnet_core.errors import ConfigError
from dsnet_core.io.reader import LogReader

SOURCE_SEED, PROBE_SEED, PROBE_SAMPLES = 1000, 2000, 4
"""The source stream's seed is ``--seed + 1000`` (never the bundled models' training seed 0), its
probe's ``--seed + 2000``; the probe holds 4 samples."""


def corrected_frames(options, logs: list[LogReader], cfg: AdaptConfig) -> tuple[list[Item], list[Item], set]:
    """``--labels DIR``: (frames trained on, frames held back, ``(sequence, frame_id)`` of all).

    Label files whose frames are in the target logs are read over the logs' scans and poses (any
    layout with ``DIR/sequences/SS/labels/ID.label``: a `dsnet review export` folder or bare labels);
    a folder of its own scans that match no target frame (a review folder of another log) is read as
    a log. ``holdout`` of them are held back for validation when that makes at least 3, else none.

    Raises:
        ConfigError: no corrected frame found, or a frame that matches frames of several logs.
    """
    if options.labels is None:
        return [], [], set()
    root = Path(options.labels).expanduser()
    items: list[Item] = []
    owner: dict[tuple[str, str], str] = {}
    for reader in logs:
        for it in volumes(LabelOverlay(reader, root), cfg.scans, cfg.label_weight, "corrected"):
            key = (it.refs[-1].sequence, it.refs[-1].frame_id)
            if key in owner:
                raise ConfigError(
                    f"{root}: corrected frame {key[0]}/{key[1]} matches frames of {owner[key]} and "
                    f"{reader.root}; give one target log per --labels folder"
                )
            owner[key] = str(reader.root)
            items.append(it)
    if not items and any((root / "sequences").glob("*/velodyne/*.bin")):
        from dsnet_core.io.formats import open_log

        items = volumes(open_log(str(root)), cfg.scans, cfg.label_weight, "corrected")
    if not items:
        raise ConfigError(
            f"{root}: no corrected frames (expected sequences/SS/labels/ID.label for frames of the target "
            "logs, or a `dsnet review export` folder)"
        )
    train, held = split(items, options.holdout, cfg.seed)
    if len(held) < MIN_HELDOUT:
        train, held = items, []
    return train, held, {(it.refs[-1].sequence, it.refs[-1].frame_id) for it in items}


def split(items: list[Item], fraction: float, seed: int) -> tuple[list[Item], list[Item]]:
    """The seeded held-back choice of :func:`dsnet_core.train.finetune.holdout_split`."""
    from dsnet_core.train.finetune import holdout_split

    if fraction <= 0:
        return items, []
    _, held = holdout_split([list(it.refs) for it in items], fraction, seed)
    names = {f"{refs[-1].sequence}/{refs[-1].frame_id}" for refs in held}
    return [it for it in items if it.name not in names], [it for it in items if it.name in names]


def source_scans(options, card, cfg: AdaptConfig, pairs: int, sensor_card=None) -> tuple[Source, list[Item]]:
    """The source of the mixed pairs and the source probe: ``--source-log`` (its first volumes are
    the probe), else the synthetic stream of the parent's training styles and sensors (as its card
    records them; ``--source-styles``/``--source-sensors`` override), every sample rendered with
    ``sensor_card``'s LiDAR when one is given (``--like`` / ``--sensor-card``)."""
    if options.source_log is not None:
        from dsnet_core.io.formats import open_log

        src = LogSource(open_log(str(options.source_log)), cfg.scans, 1.0, cfg.seed)
        return src, src.pool[:PROBE_SAMPLES]
    from dsnet_core.synth.stream import StreamOptions
    from dsnet_core.train.stream import StreamLog

    stream = card.training_data.get("stream") or {}
    styles = options.names(options.source_styles) or _listed(stream.get("styles"))
    sensors = options.names(options.source_sensors) or _listed(stream.get("sensors"))
    so = StreamOptions(frames=cfg.scans, styles=styles, sensors=sensors, card=sensor_card)
    train = StreamLog(cfg.seed + SOURCE_SEED, so, max(pairs, 1), options.stream_workers)
    probe = StreamLog(cfg.seed + PROBE_SEED, so, PROBE_SAMPLES, 0)
    return StreamSource(train, 1.0), stream_probe(probe, PROBE_SAMPLES)


def _listed(value) -> tuple[str, ...] | None:
    return tuple(value) if isinstance(value, list) and value else None
