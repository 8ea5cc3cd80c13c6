"""Instances from per-point predictions: seeds (FPS), neighbour search, dynamic shifting, the
heuristic clusterers, connected components and the semantic/instance fusion."""
