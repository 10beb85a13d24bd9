"""Lens, response-curve, colour, vignetting and photo-camera profiles (``solidkit calibrate ...``).

Modules (imported on demand; each profile is a versioned JSON file with provenance, see
:mod:`solidkit.calibration.profile`):

- :mod:`~solidkit.calibration.response` — inverse camera response from brackets (Debevec, Robertson);
- :mod:`~solidkit.calibration.colour` — white balance + 3x3 CCM from a ColorChecker, CIEDE2000;
- :mod:`~solidkit.calibration.camera` — photo-camera K (EXIF / FOV / checkerboard), resize/crop to 320x240;
- :mod:`~solidkit.calibration.fisheye` — fisheye intrinsics (Kannala-Brandt, Mei), exported to the
  lens-profile format of :mod:`solidkit.camera.lens`;
- :mod:`~solidkit.calibration.vignetting` — radial falloff per lens (flat field or lens overlap);
- :mod:`~solidkit.calibration.boards` — checkerboard detection with view rejection, synthetic rendering.

EXIF (exposure times, focal geometry) is read by :func:`solidkit.camera.metadata.read_metadata`,
the package's one EXIF reader.
"""
