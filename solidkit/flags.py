"""Flags: the review notes solidkit attaches to alignments, labels and test-set entries.

On disk a flag is one string, ``"code"`` or ``"code: detail"`` (JSON lists of strings in
``align/alignment.json`` and ``testset.json``; the label store keeps the codes alone). ``code``
says what is wrong (lower-case letters, digits, ``_``), ``detail`` says by how much, in words.
:class:`Flag` is that string parsed, and ``str(flag)`` is the string again: for every string of
the form above, ``str(Flag.parse(s)) == s``.

Code that decides on a flag reads its :attr:`Flag.code` (:func:`flag_codes`, :func:`has_code`),
never its wording; the codes solidkit writes are the members of :class:`FlagCode` (plus
:func:`disagrees_code`'s ``<cue>_disagrees``).

Examples
--------
>>> f = Flag.parse("clock_mismatch: p02 taken more than an hour from the photo")
>>> f.code, f.detail
('clock_mismatch', 'p02 taken more than an hour from the photo')
>>> str(Flag(FlagCode.PIXEL_OUTSIDE_PHOTO)), str(f) == "clock_mismatch: p02 taken more than an hour from the photo"
('pixel_outside_photo', True)
>>> flag_codes(["no_yaw: no cue gave a yaw", "pixel_outside_photo"])
['no_yaw', 'pixel_outside_photo']
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum

__all__ = ["Flag", "FlagCode", "disagrees_code", "flag_codes", "has_code"]


class FlagCode(str, Enum):
    """The flag codes solidkit writes; ``member.value``, ``str(member)`` and f-strings give the stored code."""

    # the scene and its photo (solidkit.align.pipeline)
    NO_PHOTO = "no_photo"
    ALIGN_FAILED = "align_failed"
    NO_INTRINSICS = "no_intrinsics"
    NO_PHOTO_HEADING = "no_photo_heading"
    NO_CAMERA_POSITION = "no_camera_position"
    CLOCK_MISMATCH = "clock_mismatch"
    FOCAL_REFINED = "focal_refined"
    PHOTO_POSE_DISAGREES = "photo_pose_disagrees"
    PHOTO_MATCH_FAILED = "photo_match_failed"
    PHOTO_POSE_UNKNOWN = "photo_pose_unknown"
    # a capture's yaw (solidkit.align.pipeline, solidkit.align.heading)
    NO_NORMAL_SHOT = "no_normal_shot"
    NORMAL_EXPOSURE_SUBSTITUTED = "normal_exposure_substituted"
    NO_PANORAMA = "no_panorama"
    LABEL_DIFFERS = "label_differs"
    FEATURES_FAILED = "features_failed"
    YAW_FROM_STREET_LINES = "yaw_from_street_lines"
    YAW_FROM_COMPASSES = "yaw_from_compasses"
    YAW_FROM_SKY = "yaw_from_sky"
    NO_YAW = "no_yaw"
    YAW_DOUBTFUL = "yaw_doubtful"
    SINGLE_CUE = "single_cue"
    NO_AGREEMENT = "no_agreement"
    # a probe's pixel in the photo (solidkit.align.pipeline); codes starting "pixel" concern the pixel
    PIXEL_FROM_GEOMETRY = "pixel_from_geometry"
    NO_PIXEL = "no_pixel"
    PIXEL_DISAGREES = "pixel_disagrees"
    PIXEL_OUTSIDE_PHOTO = "pixel_outside_photo"
    # the sun (solidkit.align.sun)
    SUN_CANDIDATES_REJECTED = "sun_candidates_rejected"
    AUTO_DIFFERS = "auto_differs"
    DISAGREES_WITH_SCENE = "disagrees_with_scene"
    POSITION_DISAGREES = "position_disagrees"
    NO_SUN_FOUND = "no_sun_found"
    EPHEMERIS_DISAGREES = "ephemeris_disagrees"
    EPHEMERIS_AZIMUTH_DISAGREES = "ephemeris_azimuth_disagrees"
    SUN_OFF_EPHEMERIS = "sun_off_ephemeris"
    SUN_FRAME_CONFLICT = "sun_frame_conflict"
    NO_EPHEMERIS = "no_ephemeris"
    SINGLE_POSITION = "single_position"
    # the test set (solidkit.testset.build)
    PHOTO_PITCH_ROLL_ASSUMED_ZERO = "photo_pitch_roll_assumed_zero"
    NO_SUN_FRAME = "no_sun_frame"
    SUN_FRAME_NOT_A_PANORAMA = "sun_frame_not_a_panorama"
    # review of human labels (solidkit.labeling.review)
    ANNOTATORS_DISAGREE = "annotators_disagree"
    DIFFERS_FROM_AUTO = "differs_from_auto"

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


def disagrees_code(cue: str) -> str:
    """``"<cue>_disagrees"``: the code of a yaw cue left out of its capture's consensus (``cue``: its key)."""
    return f"{cue}_disagrees"


@dataclass(frozen=True)
class Flag:
    """One flag: ``code`` (what) and ``detail`` (how much, in words; ``""``: none)."""

    code: str
    detail: str = ""

    def __post_init__(self) -> None:
        if isinstance(self.code, Enum):  # a FlagCode: its plain string
            object.__setattr__(self, "code", str(self.code.value))
        if ":" in self.code or self.code != self.code.strip():
            raise ValueError(f"flag code {self.code!r}: no ':', no surrounding spaces")

    @classmethod
    def parse(cls, text: str | Flag) -> Flag:
        """The flag a stored string holds: its code is the text before the first ``:`` (the whole
        text without one), its detail the rest without the separating space."""
        if isinstance(text, Flag):
            return text
        code, sep, detail = text.partition(":")
        return cls(code.strip(), detail.strip() if sep else "")

    def __str__(self) -> str:
        return f"{self.code}: {self.detail}" if self.detail else self.code


def flag_codes(flags: Iterable[str | Flag]) -> list[str]:
    """The code of each of ``flags`` (stored strings or :class:`Flag`), in order."""
    return [Flag.parse(f).code for f in flags]


def has_code(flags: Iterable[str | Flag], code: str) -> bool:
    """True when one of ``flags`` has ``code``."""
    return any(Flag.parse(f).code == code for f in flags)
