"""The SOLID-Net-style real test set: validation and versioning."""
