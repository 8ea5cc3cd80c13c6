"""A LiDAR estimated from its own log (``dsnet describe --sensor``) as a typed sensor card that
``dsnet synth --sensor-card`` / ``--like`` renders with (docs/sensor.md)."""

from dsnet_core.sensor.card import SensorCard, SensorCardError, load_card, parse_card
from dsnet_core.sensor.estimate import SensorEstimate, SensorEstimateError, estimate_sensor

__all__ = [
    "SensorCard",
    "SensorCardError",
    "SensorEstimate",
    "SensorEstimateError",
    "estimate_sensor",
    "load_card",
    "parse_card",
]
