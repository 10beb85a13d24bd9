"""Browser labeling app for sun centroids and probe pixels."""
