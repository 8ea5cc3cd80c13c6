"""Benchmark-exact scoring: PQ family, mIoU, LSTQ (4D-PLS) and the Panoptic nuScenes metrics."""
