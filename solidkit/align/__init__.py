"""Sun positions and rotating probes into the photo's view frame."""
