"""The camera model, below capture and calibration: lens profiles (and the shipped ones),
EXIF/XMP/maker-note metadata, raw decoding."""
