"""SOLID-Net in PyTorch and kornia: I-Net, panoramic warping, P-Net, losses."""
