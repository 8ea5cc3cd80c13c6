"""The sensor card: a small typed YAML description of a LiDAR, estimated from a log
(:func:`dsnet_core.sensor.estimate.estimate_sensor`) and rendered by ``dsnet synth --sensor-card``.

Every key is checked (unknown keys are refused) and a bad card is one :class:`SensorCardError`
line naming the file and the key: ``card.yaml: beams: must be between 1 and 512, got 0``.

Example (shortened)::

    card: 1
    name: pandaset
    beams: 2
    elevations_deg: [2.0, -24.9]
    azimuth_steps: 2048
    mount_height_m: 1.73
    ...
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from dsnet_core.errors import DataFormatError

CARD_VERSION = 1
MAX_BEAMS = 512


class SensorCardError(DataFormatError):
    """A sensor card is unreadable, or a key is missing, unknown or out of range."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RayDrop(_Strict):
    """No-return (ray-drop) rates: of the rays that hit a surface within range, the share lost.

    Attributes:
        rate: over the whole log.
        per_beam: ``(beams,)`` per beam, top beam first.
        beam_factor: ``(beams,)`` each beam's drops over those its rays' ranges predict
            (``by_range``); the renderer drops a ray at range r of beam b with probability
            ``beam_factor[b] · by_range(r)``.
        range_edges_m: ``(K + 1,)`` bin edges (metres, increasing).
        by_range: ``(K,)`` per range bin.
    """

    rate: float = Field(ge=0.0, le=1.0)
    per_beam: tuple[float, ...]
    beam_factor: tuple[float, ...]
    range_edges_m: tuple[float, ...]
    by_range: tuple[float, ...]

    @field_validator("beam_factor")
    @classmethod
    def _factor(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for i, x in enumerate(v):
            if not 0.0 <= x <= 100.0:
                raise ValueError(f"entry {i} is {x}, outside [0, 100]")
        return v

    @field_validator("per_beam", "by_range")
    @classmethod
    def _unit(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for i, x in enumerate(v):
            if not 0.0 <= x <= 1.0:
                raise ValueError(f"entry {i} is {x}, outside [0, 1]")
        return v

    @model_validator(mode="after")
    def _bins(self) -> RayDrop:
        _check_bins(self.range_edges_m, len(self.by_range), "by_range")
        return self


class Remission(_Strict):
    """The remission (0–1) distribution as quantiles at ``levels``, over the log and per range bin.

    Attributes:
        levels: ``(Q,)`` quantile levels in [0, 1], increasing (0 and 1 included).
        quantiles: ``(Q,)`` remission at each level, non-decreasing.
        range_edges_m: ``(K + 1,)`` bin edges (metres).
        by_range: ``(K, Q)`` quantiles per range bin.
        incidence_edges: ``(J + 1,)`` |cos incidence| bin edges of the ground points (informative).
        median_by_incidence: ``(J,)`` median ground remission per incidence bin (None: too few points).
    """

    levels: tuple[float, ...]
    quantiles: tuple[float, ...]
    range_edges_m: tuple[float, ...]
    by_range: tuple[tuple[float, ...], ...]
    incidence_edges: tuple[float, ...] = ()
    median_by_incidence: tuple[float | None, ...] = ()

    @model_validator(mode="after")
    def _shape(self) -> Remission:
        q = len(self.levels)
        if (
            q < 2
            or self.levels[0] != 0.0
            or self.levels[-1] != 1.0
            or any(b <= a for a, b in zip(self.levels, self.levels[1:], strict=False))
        ):
            raise ValueError("levels must increase from 0 to 1")
        for name, row in (
            ("quantiles", self.quantiles),
            *((f"by_range.{k}", r) for k, r in enumerate(self.by_range)),
        ):
            if len(row) != q:
                raise ValueError(f"{name} holds {len(row)} values, levels {q}")
            if any(not 0.0 <= x <= 1.0 for x in row) or any(b < a for a, b in itertools.pairwise(row)):
                raise ValueError(f"{name} must be non-decreasing within [0, 1]")
        _check_bins(self.range_edges_m, len(self.by_range), "by_range")
        if len(self.median_by_incidence) != max(len(self.incidence_edges) - 1, 0):
            raise ValueError("median_by_incidence needs one value per incidence bin")
        return self


class SensorOrigin(_Strict):
    """Where the sensor's optical centre is in its log's frame, and how its spin axis is tilted.

    A log exported in a vehicle frame (origin at the rear axle, or on the ground) holds the same
    scans as one in the sensor frame, moved: a log point ``p`` is at ``Rᵀ (p − xyz_m)`` in the
    sensor frame, ``R = Ry(pitch_deg) · Rx(roll_deg)`` (the sensor's axes, as columns, in the log's
    frame; no yaw: the sensor's azimuth 0 is the log's +x). All zero: the log is in the sensor frame.

    Attributes:
        xyz_m: ``(3,)`` the sensor's centre in the log's frame (metres).
        roll_deg, pitch_deg: the sensor's tilt relative to the log's axes (degrees).
    """

    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    roll_deg: float = Field(default=0.0, ge=-45.0, le=45.0)
    pitch_deg: float = Field(default=0.0, ge=-45.0, le=45.0)

    @field_validator("xyz_m")
    @classmethod
    def _near(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        for i, x in enumerate(v):
            if not -100.0 <= x <= 100.0:
                raise ValueError(f"entry {i} is {x} m, outside ±100 m")
        return v


class SensorCard(_Strict):
    """A LiDAR as ``dsnet synth`` renders it.

    Attributes:
        card: schema version (1).
        name: a label for the sensor.
        source: the log it was estimated from (informative).
        beams: number of beams (1..512).
        elevations_deg: ``(beams,)`` beam elevations, degrees, top beam first, within ±90°.
        azimuth_steps: firings per full revolution and beam (the azimuth step is 360° / this).
        fov_deg: horizontal field of view (degrees, 360 for a spinning sensor).
        fov_center_deg: azimuth of the field of view's centre (0: forward, +x; positive: left).
        scan_direction: ``counter-clockwise`` (azimuth increasing along a beam's points),
            ``clockwise``, or None (unknown).
        frame_period_s: seconds between scans (None: unknown).
        origin: :class:`SensorOrigin`, the sensor's centre and tilt in the log's frame (every other
            value is measured from that centre, in the sensor's frame).
        mount_height_m: height of the sensor above the ground (metres, ≥ 0).
        mount_pitch_deg, mount_roll_deg: the sensor's tilt relative to the ground.
        min_range_m, max_range_m: range limits (metres).
        returns_per_scan: mean number of points per scan.
        range_noise_m: standard deviation of the range error (metres).
        ray_drop: :class:`RayDrop`.
        remission: :class:`Remission`.
        not_estimated: what could not be estimated from the log, and why (key -> reason); the
            renderer uses the documented defaults there.
    """

    card: Literal[1] = CARD_VERSION
    name: str = "sensor"
    source: str = ""
    beams: int = Field(ge=1, le=MAX_BEAMS)
    elevations_deg: tuple[float, ...]
    azimuth_steps: int = Field(ge=1, le=100_000)
    fov_deg: float = Field(default=360.0, gt=0.0, le=360.0)
    fov_center_deg: float = Field(default=0.0, ge=-180.0, le=180.0)
    scan_direction: Literal["counter-clockwise", "clockwise"] | None = None
    frame_period_s: float | None = Field(default=None, gt=0.0)
    origin: SensorOrigin = Field(default_factory=SensorOrigin)
    mount_height_m: float = Field(ge=0.0, le=100.0)
    mount_pitch_deg: float = Field(default=0.0, ge=-45.0, le=45.0)
    mount_roll_deg: float = Field(default=0.0, ge=-45.0, le=45.0)
    min_range_m: float = Field(ge=0.0)
    max_range_m: float = Field(gt=0.0, le=2000.0)
    returns_per_scan: float = Field(ge=0.0)
    range_noise_m: float = Field(default=0.02, ge=0.0, le=5.0)
    ray_drop: RayDrop
    remission: Remission
    not_estimated: dict[str, str] = Field(default_factory=dict)

    @field_validator("elevations_deg")
    @classmethod
    def _angles(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        for i, x in enumerate(v):
            if not -90.0 <= x <= 90.0:
                raise ValueError(f"entry {i} is {x}°, outside ±90°")
        if any(b >= a for a, b in itertools.pairwise(v)):
            raise ValueError("must decrease strictly (top beam first)")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> SensorCard:
        if len(self.elevations_deg) != self.beams:
            raise ValueError(f"elevations_deg holds {len(self.elevations_deg)} angles for {self.beams} beams")
        for key in ("per_beam", "beam_factor"):
            n = len(getattr(self.ray_drop, key))
            if n != self.beams:
                raise ValueError(f"ray_drop.{key} holds {n} values for {self.beams} beams")
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f"min_range_m {self.min_range_m} must be below max_range_m {self.max_range_m}")
        return self

    def to_yaml(self) -> str:
        """The card as YAML text (keys in declaration order)."""
        import yaml

        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False, width=100)

    def save(self, path: str | Path) -> Path:
        """Write the card to ``path`` (parents created); returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_yaml())
        return path


def _check_bins(edges: tuple[float, ...], n: int, name: str) -> None:
    if len(edges) != n + 1:
        raise ValueError(f"{name} holds {n} bins for {len(edges)} range edges (need one fewer)")
    if any(b <= a for a, b in itertools.pairwise(edges)) or (edges and edges[0] < 0):
        raise ValueError("range_edges_m must be ≥ 0 and increase")


def _error_line(exc: ValidationError) -> str:
    err = exc.errors()[0]
    loc = ".".join(str(p) for p in err.get("loc", ())) or "card"
    msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
    if err.get("type") == "extra_forbidden":
        msg = "unknown key (see docs/sensor.md for the card's keys)"
    elif err.get("type") == "missing":
        msg = "missing key"
    elif "input" in err and not isinstance(err["input"], dict | list | tuple):
        msg = f"{msg}, got {err['input']!r}"
    return f"{loc}: {msg}"


def parse_card(data: object, path: str | Path = "<card>") -> SensorCard:
    """A card from parsed YAML (a mapping).

    Raises:
        SensorCardError: not a mapping, or the first bad key (``path: key: problem``).
    """
    if not isinstance(data, dict):
        raise SensorCardError(path, "a sensor card is a YAML mapping of keys (see docs/sensor.md)")
    try:
        return SensorCard.model_validate(data)
    except ValidationError as exc:
        raise SensorCardError(path, _error_line(exc)) from None


def load_card(path: str | Path) -> SensorCard:
    """Read and check the card at ``path``.

    Raises:
        SensorCardError: missing or unreadable file, not YAML, or a bad key (one line, naming it).
    """
    import yaml

    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SensorCardError(path, f"cannot read the sensor card ({exc.strerror or exc})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise SensorCardError(path, f"not YAML{where}") from None
    return parse_card(data, path)
