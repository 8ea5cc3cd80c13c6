"""Match a log's clouds to the sensor a model was trained on, before the network reads them.

A model trained on one sensor reads another sensor's clouds off its training distribution in two
ways that need no labels to see (issue 37/38, PandaSet): the ground sits at another height below
the cloud's origin (a sensor mounted lower or higher, or a log whose origin is not the sensor, as
PandaSet's is not: its road is 0.25–0.33 m below the origin where the synthetic training sensors'
is 1.73 m), and the remission has another scale (PandaSet's road median 0.02 where the synthetic
stream's is 0.15). ``infer.match`` (``dsnet label --match``) corrects both on the network's input
only: the stored coordinates, and every stage after ``infer``, keep the log's own frame (the
network's offsets are vectors, so they apply to the original points unchanged).

The reference is the training data's, recorded in the card (``training_data.sensor_reference``,
:func:`reference_of` over the scans the trainer probes its class counts on):

- ``ground``: the median over the reference scans of :func:`ground_below`;
- ``remission``: :data:`LEVELS` quantiles of the scans' remission.

Modes: ``ground`` translates each cloud by ``(0, 0, reference.ground − ground_below(cloud))``;
``remission`` replaces each point's remission by the reference quantile at its mid-rank in its own
cloud (``rank / (N − 1)``, ties sharing the mean of their ranks, linear between the recorded
quantiles), so any increasing recalibration of a sensor's intensity gives the same input; ``both``
does both. Everything is float64 numpy order statistics, medians and one linear interpolation:
deterministic and independent of the point order.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from dsnet_core.errors import ConfigError
from dsnet_core.model.ground_height import CELL, HALF_EXTENT, ground_grid

MATCH_MODES = ("auto", "none", "ground", "remission", "both")
LEVELS = 101
"""Remission quantiles recorded (levels 0, 0.01, …, 1)."""
RING = (5.0, 15.0)
"""The ground under the sensor: cells whose centres lie this far from the origin (metres), past
the ego vehicle's own returns and before the ground fit's far, sparse cells."""
_QUANTILES = np.linspace(0.0, 1.0, LEVELS)


def ground_below(xyz: np.ndarray) -> float | None:
    """The ground's z around the cloud's origin: the median ground-fit height
    (:func:`~dsnet_core.model.ground_height.ground_grid`) of the cells with returns whose centres
    lie :data:`RING` metres from the origin.

    Args:
        xyz: float ``(N, 3)`` metres.

    Returns:
        metres, or None where no cell of the ring has a return.
    """
    p = np.asarray(xyz, np.float64)
    if p.shape[0] == 0:
        return None
    near = p[np.hypot(p[:, 0], p[:, 1]) <= RING[1] + 2 * CELL]
    if near.shape[0] == 0:
        return None
    n = round(2 * HALF_EXTENT / CELL)
    grid = ground_grid(near)
    ix = np.clip(np.floor((near[:, 0] + HALF_EXTENT) / CELL), 0, n - 1).astype(np.int64)
    iy = np.clip(np.floor((near[:, 1] + HALF_EXTENT) / CELL), 0, n - 1).astype(np.int64)
    filled = np.zeros(n * n, bool)
    filled[ix * n + iy] = True
    centre = -HALF_EXTENT + CELL * (np.arange(n) + 0.5)
    dist = np.hypot(centre[:, None], centre[None, :]).ravel()
    ring = filled & (dist >= RING[0]) & (dist <= RING[1])
    if not ring.any():
        return None
    return float(np.median(grid.ravel()[ring]))


@dataclass(frozen=True)
class SensorReference:
    """What a model's training clouds looked like (module docstring).

    Attributes:
        ground: the ground's z below the training sensor, metres (e.g. −1.73).
        remission: :data:`LEVELS` non-decreasing remission quantiles in [0, 1].
    """

    ground: float
    remission: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"ground": self.ground, "remission_quantiles": list(self.remission)}

    @classmethod
    def from_dict(cls, data: Any, where: str) -> SensorReference:
        """Parse a card's ``sensor_reference``.

        Raises:
            ConfigError: one line naming ``where`` and what is wrong.
        """
        try:
            ground = float(data["ground"])
            rem = tuple(float(v) for v in data["remission_quantiles"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: sensor_reference is malformed ({exc!r})") from None
        q = np.asarray(rem)
        if not np.isfinite(ground) or abs(ground) > 10:
            raise ConfigError(f"{where}: sensor_reference ground {ground} m is not a ground height")
        if len(rem) != LEVELS or not np.isfinite(q).all() or np.any(np.diff(q) < 0):
            raise ConfigError(
                f"{where}: sensor_reference needs {LEVELS} non-decreasing finite remission quantiles"
            )
        return cls(ground, rem)


def reference_of(clouds: Iterable[np.ndarray]) -> SensorReference:
    """The reference of training clouds: float ``(N, ≥4)`` each (x, y, z, remission).

    Ground rounded to the millimetre and quantiles to 1e-4, so the record is the same on every CPU.

    Raises:
        ValueError: no cloud has a ground (or there is no point).
    """
    grounds: list[float] = []
    rems: list[np.ndarray] = []
    for cloud in clouds:
        c = np.asarray(cloud)
        g = ground_below(c[:, :3])
        if g is not None:
            grounds.append(g)
        rems.append(np.asarray(c[:, 3], np.float64))
    values = np.concatenate(rems) if rems else np.zeros(0)
    if not grounds or values.size == 0:
        raise ValueError("no training cloud has ground returns near the sensor")
    q = np.round(np.quantile(values, _QUANTILES), 4)
    quantiles = tuple(float(v) for v in np.maximum.accumulate(q))
    return SensorReference(round(float(np.median(grounds)), 3), quantiles)


def mid_rank(values: np.ndarray) -> np.ndarray:
    """float64 ``(N,)`` empirical quantile of each of ``values`` ``(N,)``: mid-rank / (N − 1), ties
    sharing the mean of their ranks (0.5 for a single value)."""
    v = np.asarray(values)
    n = v.shape[0]
    if n <= 1:
        return np.full(n, 0.5)
    _, inverse, counts = np.unique(v, return_inverse=True, return_counts=True)
    start = np.cumsum(counts) - counts
    mid = start + (counts - 1) / 2.0
    return mid[inverse] / (n - 1)


@dataclass(frozen=True)
class SensorMatch:
    """A cloud transform toward ``reference`` (``mode``: ``ground``, ``remission`` or ``both``)."""

    reference: SensorReference
    mode: str

    def __post_init__(self) -> None:
        if self.mode not in MATCH_MODES[2:]:
            raise ConfigError(f"match must be one of {', '.join(MATCH_MODES)}, got {self.mode!r}")

    def __call__(self, cloud: np.ndarray) -> np.ndarray:
        """float ``(N, ≥4)`` → a new float32 ``(N, 4)`` cloud as the network should read it."""
        out = np.array(np.asarray(cloud)[:, :4], np.float32, copy=True)
        if out.shape[0] == 0:
            return out
        if self.mode in ("ground", "both"):
            g = ground_below(out[:, :3])
            if g is not None:
                out[:, 2] += np.float32(self.reference.ground - g)
        if self.mode in ("remission", "both"):
            out[:, 3] = np.interp(mid_rank(out[:, 3]), _QUANTILES, np.asarray(self.reference.remission))
        return out


def auto_mode(training_data: dict) -> str:
    """What ``auto`` means for a card: ``ground`` when it was trained (or fine-tuned) on a stream
    rendered with a sensor card (``--stream-like``/``--sensor-card``: it learned that sensor's own
    frame, which a log's origin need not be) and records its reference, else ``none``."""
    stream = training_data.get("stream") or {}
    return "ground" if stream.get("sensor_card") and training_data.get("sensor_reference") else "none"


def card_reference(training_data: dict, where: str) -> SensorReference | None:
    """A card's ``training_data.sensor_reference`` (None when it has none)."""
    data = training_data.get("sensor_reference")
    return None if data is None else SensorReference.from_dict(data, where)
