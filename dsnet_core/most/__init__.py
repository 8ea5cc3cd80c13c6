"""MOST: modal detection on a bird's-eye view of the shared backbone, point membership by
PointSegMLP, and velocity-based tracking targets (docs/most.md)."""
