"""Lens, response-curve, colour and photo-camera profiles (see the Calibration issue)."""
