"""Training, the paper's metrics and sim-to-real fine-tuning."""
