"""Training of the DS-Net network: data, augmentation, the staged loop, resumable state."""
