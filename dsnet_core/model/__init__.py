"""The network: cylindrical voxelisation, sparse convolution in torch, the Cylinder3D backbone,
the semantic and instance heads, losses, checkpoints and the inference API."""
