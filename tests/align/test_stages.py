"""The steps of align's two orchestrations, each on its own: the sun's choice (solidkit.align.sun) and a
scene's alignment (solidkit.align.pipeline), on hand-made inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from solidkit.align.captures import Capture
from solidkit.align.ephemeris import DRIFT_HOURS, at_photo_time, hours_apart
from solidkit.align.geometry import LevelPoseFit
from solidkit.align.pipeline import (
    AlignSettings,
    CaptureView,
    ProbePixel,
    capture_yaw,
    clock_mismatch,
    compass_cue,
    explain_rejections,
    probe_pixel,
)
from solidkit.align.schema import (
    CaptureSun,
    Cue,
    Ephemeris,
    Levelling,
    PhotoInfo,
    ProbeAlignment,
    SceneSun,
    SunCandidate,
    photo_azimuth_from_solar,
    solar_azimuth_from_photo,
    wrap_deg,
)
from solidkit.align.sun import (
    Blob,
    CaptureSunInput,
    SunScene,
    SunSettings,
    best_hypothesis,
    capture_results,
    choose_candidates,
    choose_sun,
    consensus,
    hard_rejections,
    scene_sun,
)
from solidkit.capture.manifest import Probe
from solidkit.envmap.coords import direction_from_angles
from solidkit.flags import FlagCode, flag_codes

STATIC = SunSettings(sun_moves=False)


def _eph(az: float, el: float, time: str = "2024-06-01T12:00:00+00:00") -> Ephemeris:
    return Ephemeris(time_utc=time, latitude_deg=45.0, longitude_deg=7.0, azimuth_deg=az, elevation_deg=el)


def _blob(az: float, el: float, size: float = 0.9, sky: float | None = 0.9, contrast: float = 20.0) -> Blob:
    d = direction_from_angles(math.radians(az), math.radians(el))
    return Blob(d, az, el, size, 40, contrast, sky)


def _cap(pid: str, blobs: list[Blob], yaw: float | None, **kw) -> CaptureSunInput:
    return CaptureSunInput(pid, blobs, kw.pop("eph", _eph(200.0, 35.0)), yaw, None if yaw is None else 0.3, **kw)


# --------------------------------------------------------------------------- frames and times
def test_solar_azimuth_to_the_photo_frame_and_back() -> None:
    assert photo_azimuth_from_solar(200.0, 180.0) == 20.0
    assert photo_azimuth_from_solar(10.0, 350.0) == 20.0 and photo_azimuth_from_solar(350.0, 10.0) == -20.0
    for az, h in ((200.0, 180.0), (10.0, 350.0), (-179.0, 12.5)):
        assert solar_azimuth_from_photo(photo_azimuth_from_solar(az, h), h) == pytest.approx(az % 360.0)


def test_the_sun_moves_to_the_photo_time_within_an_hour() -> None:
    cap, photo = _eph(190.0, 34.0, "2024-06-01T11:40:00+00:00"), _eph(200.0, 35.0)
    assert hours_apart(cap, photo) == pytest.approx(1 / 3)
    assert at_photo_time(10.0, 30.0, cap, photo) == (20.0, 31.0)
    assert at_photo_time(10.0, 30.0, cap, photo, sun_moves=False) == (10.0, 30.0)
    assert at_photo_time(10.0, 30.0, None, photo) == (10.0, 30.0)
    far = _eph(150.0, 20.0, "2024-06-01T09:00:00+00:00")
    assert hours_apart(far, photo) > DRIFT_HOURS and at_photo_time(10.0, 30.0, far, photo) == (10.0, 30.0)


# --------------------------------------------------------------------------- the sun, step by step
def test_hard_rejections_say_why() -> None:
    caps = [
        _cap(
            "cam",
            [_blob(20.0, 35.0), _blob(60.0, 30.0, size=4.0), _blob(-40.0, 35.0, sky=0.1), _blob(100.0, -5.0)],
            0.0,
        )
    ]
    hard = hard_rejections(caps, STATIC)
    assert hard[0, 0] == []
    assert "too large for the sun" in hard[0, 1][0]
    assert "not in the sky" in hard[0, 2][0]
    assert "below the horizon" in hard[0, 3][0]


def test_an_agreement_on_elevation_alone_counts_half() -> None:
    """p1 has no yaw: it supports the camera's candidate on elevation only (half a capture)."""
    caps = [_cap("cam", [_blob(20.0, 35.0)], 0.0), _cap("p1", [_blob(-50.0, 35.0)], None)]
    scene = SunScene(caps, _eph(200.0, 35.0), 180.0, STATIC)
    a = scene.agrees(20.0, 35.0, 0.3, 1, 0)
    assert a.ok and a.elevation_only
    assert not scene.agrees(20.0, 40.0, 0.3, 1, 0).ok
    best, hard = best_hypothesis(scene, hard_rejections(caps, STATIC))
    assert (best.ci, best.bi) == (0, 0) and best.members == {0: 0, 1: 0}
    assert best.ephemeris_elevation_ok and best.ephemeris_azimuth_ok
    assert best.score == pytest.approx(1.5 + 1.5 + STATIC.ephemeris_azimuth_weight + 0.01 * 20 / 50)
    assert hard == hard_rejections(caps, STATIC)  # nothing rejected on the way


def test_a_candidate_seen_once_and_off_the_ephemeris_is_rejected_as_a_glint() -> None:
    caps = [_cap("cam", [_blob(-30.0, 35.0)], 0.0), _cap("p1", [], 10.0)]
    scene = SunScene(caps, _eph(200.0, 35.0), 180.0, STATIC)  # the ephemeris: azimuth +20 in the photo frame
    best, hard = best_hypothesis(scene, hard_rejections(caps, STATIC))
    assert best is None and "seen from this position only" in hard[0, 0][0]


def test_an_outranked_candidate_is_named_by_index() -> None:
    """p1 (no yaw) sees the sun and a glint at the same elevation: the closer one (through its compass) is
    chosen, the other passed every test and is outranked."""
    caps = [
        _cap("cam", [_blob(20.0, 35.0)], 0.0),
        _cap("p1", [_blob(-60.0, 35.0), _blob(40.0, 35.0)], None, compass_yaw_deg=80.0),
    ]
    scene = SunScene(caps, _eph(200.0, 35.0), 180.0, STATIC)
    best, hard = best_hypothesis(scene, hard_rejections(caps, STATIC))
    chosen, hard = choose_candidates(scene, best, hard)
    assert chosen == {0: 0, 1: 0}
    results, outranked = capture_results(scene, best, hard, chosen)
    assert outranked == {(1, 1)}
    assert results[1].candidates[1].reasons == ["another candidate fits better"] and results[1].candidates[0].chosen
    choice = choose_sun(caps, photo_ephemeris=_eph(200.0, 35.0), photo_heading_deg=180.0, settings=STATIC)
    assert choice.outranked == {("p1", 1)}
    assert choice.sun == scene_sun(caps, photo_ephemeris=_eph(200.0, 35.0), photo_heading_deg=180.0, settings=STATIC)


def test_consensus_flags_by_code() -> None:
    caps = [_cap("cam", [_blob(20.0, 35.0)], 0.0), _cap("p1", [], 10.0)]
    scene = SunScene(caps, _eph(200.0, 30.0), 180.0, STATIC)
    results = [
        CaptureSun(probe="cam", found=True, azimuth_deg=20.0, elevation_deg=35.0, uncertainty_deg=0.2),
        CaptureSun(probe="p1", found=False),
    ]
    sun = consensus(scene, results)
    assert sun.found and sun.n_captures == 1 and sun.azimuth_deg == pytest.approx(20.0)
    assert sun.world_azimuth_deg == pytest.approx(200.0)
    assert flag_codes(sun.flags) == [FlagCode.EPHEMERIS_DISAGREES, FlagCode.SINGLE_POSITION]
    none = consensus(
        SunScene(caps, None, None, STATIC), [CaptureSun(probe="cam", found=False), CaptureSun(probe="p1", found=False)]
    )
    assert not none.found and none.flags == [FlagCode.NO_SUN_FOUND.value]


# --------------------------------------------------------------------------- a scene, step by step
def _view(
    pid: str,
    *,
    heading: float | None = None,
    eph: Ephemeris | None = None,
    pixel: list[float] | None = None,
    flags: tuple[str, ...] = (),
) -> CaptureView:
    cap = Capture("s1", Probe(id=pid, shots=[], photo_pixel=pixel), None, None, None, [])
    return CaptureView(cap, heading=heading, ephemeris=eph, flags=flags)


def test_compass_cue_and_clock_mismatch() -> None:
    s = AlignSettings()
    cue = compass_cue(_view("p1", heading=350.0), 10.0, s)
    assert cue.ok and cue.yaw_deg == -20.0 and cue.sigma_deg == s.sun.compass_sigma_deg
    assert not compass_cue(_view("p1"), 10.0, s).ok and compass_cue(_view("p1", heading=1.0), None, s).yaw_deg is None
    photo = _eph(200.0, 35.0)
    views = [_view("cam", eph=photo), _view("p1", eph=_eph(150.0, 20.0, "2024-06-01T09:00:00+00:00")), _view("p2")]
    (flag,) = clock_mismatch(photo, views)
    assert flag.startswith("clock_mismatch: p1 taken more than an hour")
    assert clock_mismatch(None, views) == [] and clock_mismatch(photo, views[:1]) == []


def test_capture_yaw_fuses_and_a_human_label_wins() -> None:
    class Label:
        value, source, annotator = {"yaw_deg": 25.0}, "annotator", "ann"

    cues = {"compass": Cue(yaw_deg=20.0, sigma_deg=8.0, ok=True), "features": Cue(yaw_deg=None, ok=False)}
    cy = capture_yaw(_view("p1", flags=("no_normal_shot: x",)), cues, [], None)
    assert cy.yaw_deg == pytest.approx(20.0) and cy.source == "auto"
    assert flag_codes(cy.flags) == ["no_normal_shot", FlagCode.SINGLE_CUE, FlagCode.FEATURES_FAILED]
    cues = {"compass": Cue(yaw_deg=20.0, sigma_deg=8.0, ok=True)}
    cy = capture_yaw(_view("p1"), cues, ["yaw_from_sky: x"], Label())
    assert cy.yaw_deg == 25.0 and cy.source == "annotator" and "label" in cues
    assert flag_codes(cy.flags) == [FlagCode.SINGLE_CUE, FlagCode.LABEL_DIFFERS]  # link flags only with a linked cue


def test_probe_pixel_from_field_notes_checked_against_the_geometry() -> None:
    s = AlignSettings()
    K = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
    photo = PhotoInfo(path="p.jpg", sha256="0", size=[640, 480], K_full=K, pitch_deg=0.0, roll_deg=0.0)
    # the probe straight ahead of the camera: t = -R c with c = +z (yaw 0)
    fit = LevelPoseFit(0.0, np.array([0.0, 0.0, -1.0]), np.ones(30, bool), 0.001, 0.001, t_support=30, t_sigma=0.01)
    px = probe_pixel(_view("p1", pixel=[320.0, 240.0]), fit, None, photo, 0.0, s)
    assert px.pixel_source == "field_notes" and px.pixel_geometry == pytest.approx([320.0, 240.0])
    assert px.pixel_error_px == pytest.approx(0.0) and px.flags == ()
    px = probe_pixel(_view("p1", pixel=[620.0, 240.0]), fit, None, photo, 0.0, s)
    assert flag_codes(px.flags) == [FlagCode.PIXEL_DISAGREES] and px.pixel_error_deg > s.pixel_tolerance_deg
    # 31 deg off, but the camera position's yaw is known to 8 deg only (its compass): no telling
    px = probe_pixel(_view("p1", pixel=[620.0, 240.0]), fit, None, photo, 0.0, s, yaw_cam_sigma=8.0)
    assert px.flags == () and px.pixel_error_deg > s.pixel_tolerance_deg
    px = probe_pixel(_view("p1"), fit, None, photo, 0.0, s)
    assert px.pixel_source == "geometry" and flag_codes(px.flags) == [FlagCode.PIXEL_FROM_GEOMETRY]
    px = probe_pixel(_view("p1", pixel=[700.0, 240.0]), None, None, photo, None, s)
    assert px.pixel_geometry is None and flag_codes(px.flags) == [FlagCode.PIXEL_OUTSIDE_PHOTO]
    assert probe_pixel(_view("p1"), None, None, photo, None, s) == ProbePixel(
        flags=(
            px.flags[0].replace(
                "pixel_outside_photo",
                "no_pixel: no marked pixel and no relative pose with parallax to the camera position",
            ),
        )
    )


def test_outranked_candidates_are_explained_once_the_yaw_is_known() -> None:
    cands = [
        SunCandidate(azimuth_deg=-60.0, elevation_deg=35.0, size_deg=0.9, n_pixels=40, contrast=20.0, chosen=True),
        SunCandidate(
            azimuth_deg=40.0,
            elevation_deg=35.0,
            size_deg=0.9,
            n_pixels=40,
            contrast=20.0,
            reasons=["another candidate fits better"],
        ),
    ]
    sun = SceneSun(
        found=True,
        azimuth_deg=20.0,
        elevation_deg=35.0,
        captures=[CaptureSun(probe="p1", found=True, azimuth_deg=-60.0, elevation_deg=35.0, candidates=cands)],
    )
    lev = Levelling(pitch_deg=0.0, roll_deg=0.0, source="none")
    probes = [ProbeAlignment(id="p1", role="probe", levelling=lev, rotation=np.eye(3).tolist(), yaw_deg=80.0)]
    explain_rejections(sun, frozenset(), probes)
    assert cands[1].reasons == ["another candidate fits better"]  # not outranked: left alone
    explain_rejections(sun, frozenset({("p1", 1)}), probes)
    assert cands[1].reasons[0].startswith("not where the scene's sun is: ") and "glint" in cands[1].reasons[0]
    d = math.degrees(
        math.acos(
            math.sin(math.radians(35.0)) ** 2
            + math.cos(math.radians(35.0)) ** 2 * math.cos(math.radians(wrap_deg(40.0 + 80.0 - 20.0)))
        )
    )
    assert cands[1].scores["distance_to_scene_sun_deg"] == pytest.approx(d)
    assert cands[0].reasons == []


def test_a_photo_without_exif_intrinsics_gets_the_assumed_60_degree_view_and_a_flag(tmp_path):
    """No focal length in the photo's EXIF: K of a 60° horizontal field of view, flagged ``no_intrinsics``
    (the scene is still aligned, not dropped)."""
    import math

    from solidkit.align.captures import photo_shot_of
    from solidkit.align.pipeline import _photo_info
    from solidkit.capture.manifest import load_manifest
    from solidkit.envmap.perspective import intrinsics_from_fov
    from solidkit.flags import Flag, FlagCode
    from tests.support.testset_campaign import PHOTO, make_campaign

    make_campaign(tmp_path / "camp")
    manifest = load_manifest(tmp_path / "camp")
    scene = manifest.scenes[0]
    shot = photo_shot_of(manifest, scene)
    assert shot is not None
    w, h = PHOTO
    shot.metadata.update(path=shot.original, width=w, height=h)  # a camera's EXIF without any focal length
    for key in ("focal_length_mm", "focal_length_35mm", "focal_plane_px_per_mm", "exif_width"):
        shot.metadata.pop(key, None)
    info, flags = _photo_info(tmp_path / "camp", manifest, scene)
    assert info is not None and info.K_source == "assumed-hfov-60"
    assert info.K_full == intrinsics_from_fov(math.radians(60.0), w, h).tolist()
    assert str(FlagCode.NO_INTRINSICS) in [Flag.parse(f).code for f in flags]


# --------------------------------------------------------------------------- one frame chain, doubts at the probes
def _bare_view(pid: str) -> CaptureView:
    return CaptureView(Capture("scene01", Probe(id=pid, shots=[]), None, None, None, []))


def _probe(pid: str, yaw: float, cues: dict[str, Cue], sigma: float = 0.2, flags: list[str] | None = None):
    lev = Levelling(pitch_deg=0.0, roll_deg=0.0, source="none")
    return ProbeAlignment(
        id=pid,
        role="camera" if pid == "cam" else "probe",
        levelling=lev,
        rotation=np.eye(3).tolist(),
        yaw_deg=yaw,
        yaw_sigma_deg=sigma,
        cues=cues,
        flags=flags or [],
    )


def test_the_sun_reaches_the_photo_frame_through_the_final_yaws() -> None:
    """The consensus took p1's yaw before the sun (features, 75 deg off); the final yaws (the probes' rotations) put
    the sun elsewhere: the final yaws win, and the flag says which cue lost. A sun seen only from captures without a
    yaw before the sun gets its azimuth from their final yaws (it is not 'no sun')."""
    from solidkit.align.pipeline import sun_through_final_yaws

    caps = [
        CaptureSun(probe="cam", found=True, azimuth_deg=30.0, elevation_deg=35.0, uncertainty_deg=0.1),
        CaptureSun(probe="p1", found=True, azimuth_deg=-50.0, elevation_deg=35.0, uncertainty_deg=0.1),
    ]
    sun = SceneSun(found=True, azimuth_deg=-5.0, elevation_deg=35.0, uncertainty_deg=0.2, captures=caps)
    cues = {
        "cam": {"photo_features": Cue(yaw_deg=-10.0, sigma_deg=0.1, ok=True)},
        "p1": {
            "features": Cue(yaw_deg=145.0, sigma_deg=0.2, ok=False, residual_deg=75.0),
            "sun": Cue(yaw_deg=70.0, sigma_deg=0.3, ok=True),
            "compass": Cue(yaw_deg=72.0, sigma_deg=8.0, ok=True),
        },
    }
    final = {"cam": (-10.0, 0.1), "p1": (70.0, 0.3)}
    views = [_bare_view("cam"), _bare_view("p1")]
    sun_through_final_yaws(sun, views, final, cues, None, 180.0, AlignSettings(sun=STATIC))
    assert sun.azimuth_deg == pytest.approx(20.0, abs=0.01)
    assert sun.world_azimuth_deg == pytest.approx(200.0, abs=0.01)
    conflict = next(f for f in sun.flags if f.startswith("sun_frame_conflict"))
    assert (
        "-5.0 deg" in conflict
        and "20.0 deg" in conflict
        and "p1: yaw from sun, compass; lost: features (+75.0" in (conflict)
    )
    # the same sun without any yaw before it: elevation only in the consensus, azimuth from the final yaws
    sun = SceneSun(found=True, azimuth_deg=None, elevation_deg=35.0, uncertainty_deg=0.2, captures=caps)
    sun_through_final_yaws(sun, views, final, cues, None, 180.0, AlignSettings(sun=STATIC))
    assert sun.azimuth_deg == pytest.approx(20.0, abs=0.01) and not sun.flags
    # agreeing paths: nothing changes
    sun = SceneSun(found=True, azimuth_deg=20.3, elevation_deg=35.0, uncertainty_deg=0.2, captures=caps)
    sun_through_final_yaws(sun, views, final, cues, None, 180.0, AlignSettings(sun=STATIC))
    assert sun.azimuth_deg == 20.3 and not sun.flags


def test_doubts_reach_every_probe_they_touch() -> None:
    """A yaw that may be more than 2 deg off is flagged at its probe: a wide sigma; a yaw from a flagged sun; a yaw
    relative to a camera position whose own yaw is doubtful (a scene-level doubt reaches every capture it touched);
    a good yaw stays unflagged."""
    from solidkit.align.pipeline import flag_doubtful_yaws

    def cues(**kw: float) -> dict[str, Cue]:
        return {k: Cue(yaw_deg=v, sigma_deg=0.2, ok=True) for k, v in kw.items()}

    good = SceneSun(found=True, azimuth_deg=20.0, elevation_deg=35.0)
    probes = [
        _probe("cam", 0.0, cues(photo_features=0.0)),
        _probe("p1", 10.0, cues(features=10.0)),
        _probe("p2", 20.0, cues(compass=20.0, sun=20.0), sigma=1.5),
    ]
    flag_doubtful_yaws(good, probes, "cam")
    assert [FlagCode.YAW_DOUBTFUL.value in flag_codes(p.flags) for p in probes] == [False, False, True]
    assert "three sigmas of its yaw are 4.5 deg" in probes[2].flags[-1]

    bad = SceneSun(found=True, azimuth_deg=20.0, elevation_deg=35.0, flags=["ephemeris_azimuth_disagrees: +37.0 deg"])
    probes = [
        _probe("cam", 0.0, cues(photo_features=0.0, sun=0.1)),
        _probe("p1", 10.0, cues(features=10.0)),
        _probe("p2", 20.0, cues(features_via_p1=20.0)),
        _probe("p3", 30.0, cues(compass=30.0), sigma=0.2, flags=["single_cue: yaw from compass only"]),
    ]
    flag_doubtful_yaws(bad, probes, "cam")
    doubts = {p.id: [f for f in p.flags if f.startswith("yaw_doubtful")] for p in probes}
    assert "uses the scene's sun, which is flagged ephemeris_azimuth_disagrees" in doubts["cam"][0]
    assert "relative to cam's, which is flagged yaw_doubtful" in doubts["p1"][0]
    assert "relative to p1's" in doubts["p2"][0]
    assert doubts["p3"] == []  # already flagged single_cue


def test_a_bracket_missing_its_probe_exposure_is_flagged() -> None:
    """The LDR probe from the 1/640 s shot of a bracket without its 1/2500 s one: flagged with the substitute and how
    much brighter it is; the protocol's exposure (or a quarter stop from it) is not."""
    from solidkit.align.pipeline import exposure_substitute
    from solidkit.capture.manifest import Shot

    def shot(t: float) -> Shot:
        meta = {"exposure_time": t}
        return Shot(
            sha256="0" * 64,
            original="x.jpg",
            size=1,
            file_format="jpeg",
            sources=[],
            kind="bracket_member",
            metadata=meta,
        )

    flag = exposure_substitute(shot(1 / 640))
    assert flag == (
        "normal_exposure_substituted: the LDR probe is made from the 1/640 s shot: the protocol's 1/2500 s is "
        "missing (3.9x brighter)"
    )
    assert exposure_substitute(shot(1 / 2500)) is None and exposure_substitute(shot(1 / 2200)) is None


def test_probes_follow_the_camera_positions_final_yaw() -> None:
    """The camera position's yaw before the sun came from its compass (8 deg); the sun corrected it by 3 deg: the
    probes' features cues (relative poses turned by it) are turned by the final yaw, with its sigma, and so are the
    cues chained through them; a correction under 0.2 deg changes nothing."""
    from solidkit.align.pipeline import CameraFeatures, rebase_on_camera

    views = [_bare_view("cam"), _bare_view("p1"), _bare_view("p2")]
    pre_sigma = 8.0

    def cues() -> dict[str, dict[str, Cue]]:
        return {
            "cam": {"compass": Cue(yaw_deg=10.0, sigma_deg=8.0, ok=True)},
            "p1": {"features": Cue(yaw_deg=50.0, sigma_deg=math.hypot(0.2, pre_sigma), ok=True)},
            "p2": {
                "features_via_p1": Cue(yaw_deg=-70.0, sigma_deg=8.1, ok=True),
                "compass": Cue(yaw_deg=-66.0, ok=True),
            },
        }

    cf = CameraFeatures(10.0, {}, {}, pre_sigma)
    c = cues()
    rebase_on_camera(views, c, views[0], cf, (13.0, 3.0))
    assert c["p1"]["features"].yaw_deg == pytest.approx(53.0)
    assert c["p1"]["features"].sigma_deg == pytest.approx(math.hypot(0.2, 3.0))
    assert c["p2"]["features_via_p1"].yaw_deg == pytest.approx(-67.0) and c["p2"]["compass"].yaw_deg == -66.0
    c = cues()
    rebase_on_camera(views, c, views[0], cf, (10.1, 3.0))
    assert c == cues()
