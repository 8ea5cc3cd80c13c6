"""Synthetic driving logs: a procedural street ray-cast by a spinning multi-beam LiDAR, written in the
SemanticKITTI layout so tests and the demo run the same code path as real data."""

from dsnet_core.synth.config import SynthConfig
from dsnet_core.synth.log import generate_log, kitti_tr, plan_sequence
from dsnet_core.synth.sensor import SENSORS, LidarSpec, get_sensor

__all__ = ["SENSORS", "LidarSpec", "SynthConfig", "generate_log", "get_sensor", "kitti_tr", "plan_sequence"]
