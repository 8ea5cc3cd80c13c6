"""Ground truth standing in for the network (tests and benchmarks): centres, noise, features and
an oracle labelling path through the real clustering, fusion and stitching."""
