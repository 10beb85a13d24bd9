"""``solidkit calibrate ...``: lens, response, colour, vignetting and photo-camera profiles.

Every command writes its profile JSON atomically to ``-o/--out`` (with provenance: inputs and
their SHA-256, date, solidkit version, and the fit's residuals) and prints a short summary, or with
``--json`` the profile itself as JSON on stdout (progress goes to stderr). Angles are degrees at
this edge (conventions §6).
"""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from solidkit.calibration.boards import CharucoTarget, detect_views, read_views
from solidkit.calibration.camera import calibrate_camera_from_board, calibrate_camera_from_photo
from solidkit.calibration.colour import calibrate_colour, read_linear_image
from solidkit.calibration.fisheye import ModelName, calibrate_fisheye, lens_profile_from_calibrations
from solidkit.calibration.lensfit import FAMILIES, fit_file
from solidkit.calibration.overlap import refine_files
from solidkit.calibration.response import Method, ResponseProfile, calibrate_response_files, plot_response
from solidkit.calibration.vignetting import falloff, fit_flat_field, fit_overlap, lenses_from_profile, make_profile
from solidkit.camera.lens import load_profile as load_lens_profile
from solidkit.cli.output import echo_json
from solidkit.cli.parsing import parse_angle, parse_angles, parse_exposures, parse_floats, parse_grid
from solidkit.errors import InputError

app = typer.Typer(no_args_is_help=True)
console = Console()  # the summaries (stdout)
status = Console(stderr=True)  # progress
JSON = typer.Option(False, "--json", help="Print the profile written as JSON (instead of the summary).")


def _print_json(profile, out: Path, **extra) -> None:
    echo_json({"output": str(out), **extra, "profile": profile.model_dump(mode="json")})


def _target(pattern: str | None, charuco: str | None, square: float, marker_ratio: float, dictionary: str):
    """The board: a checkerboard's inner corners (``--pattern``) or a ChArUco target (``--charuco``)."""
    if (pattern is None) == (charuco is None):
        raise InputError(
            "give exactly one of --pattern COLSxROWS (checkerboard inner corners) or --charuco COLSxROWS (squares)"
        )
    if charuco is not None:
        return CharucoTarget(parse_grid(charuco, "--charuco"), square, marker_ratio, dictionary)
    assert pattern is not None  # exactly one of the two is given
    return parse_grid(pattern, "--pattern")


def _fmt(x: float | None, spec: str = ".3g") -> str:
    return "-" if x is None else format(x, spec)


# ------------------------------------------------------------------------------------- response
@app.command()
def response(
    frames: list[Path] = typer.Argument(..., help="Aligned bracket frames (8-bit JPEG/PNG/TIFF)."),
    out: Path = typer.Option(..., "-o", "--out", help="Profile JSON to write (a plot is written beside it as .png)."),
    times: str | None = typer.Option(
        None, "--times", help="Exposure times in seconds, comma-separated, e.g. 1/8,1/2,2 (default: EXIF)."
    ),
    method: str = typer.Option("debevec", "--method", help="debevec (default) or robertson."),
    samples: int = typer.Option(400, min=1, help="Debevec: pixel samples."),
    smoothness: float | None = typer.Option(
        None, help="Debevec: smoothness weight lambda (default 10 x samples / 70, as capture merge estimates)."
    ),
    plot: bool = typer.Option(True, "--plot/--no-plot", help="Save the curve plot beside the profile."),
    as_json: bool = JSON,
) -> None:
    """Camera response curve (inverse, per channel) from exposure brackets."""
    t = parse_exposures(times, "--times", count=len(frames)) if times is not None else None
    with status.status("fitting the response curve"):
        prof = calibrate_response_files(
            frames,
            t,
            method=cast(Method, method),
            samples=samples,  # checked there
            smoothness=smoothness,
        )
    prof.save(out)
    png = (
        plot_response(prof.array(), out.with_suffix(".png"), title=f"inverse response ({prof.method})")
        if plot
        else None
    )
    if as_json:
        _print_json(prof, out, plot=None if png is None else str(png))
        return
    table = Table(title=f"response curve ({prof.method})", show_header=False)
    table.add_row(
        "frames / exposure times", f"{len(frames)} / " + ", ".join(f"{x:g}" for x in prof.exposure_times_s) + " s"
    )
    san = prof.sanity
    bad = san["non_monotonic_codes"]
    table.add_row(
        "monotonic (smoothed)",
        "yes"
        if san["monotonic"]
        else "[red]no[/]: " + ", ".join(f"{ch} {len(b)} codes ({b[0]}..{b[-1]})" for ch, b in zip("RGB", bad) if b),
    )
    if "monotonic_fix_max_stops" in san and san["monotonic_fix_max_stops"] > 1e-3:
        table.add_row(
            "saved curve", f"made strictly increasing (moved by up to {san['monotonic_fix_max_stops']:.3f} stops)"
        )
    table.add_row("codes observed (R, G, B)", ", ".join(f"{c:.0%}" for c in san.get("coverage_fraction", [])))
    table.add_row("dynamic range codes 1..254", ", ".join(f"{d:.1f}" for d in san["dynamic_range_stops"]) + " stops")
    table.add_row(
        "radiance disagreement (RMS)", ", ".join(f"{r:.3f}" for r in prof.residuals["rms_stops_per_channel"]) + " stops"
    )
    if png is not None:
        table.add_row("plot", str(png))
    table.add_row("profile", str(out))
    console.print(table)


# --------------------------------------------------------------------------------------- colour
@app.command()
def colour(
    image: Path = typer.Argument(
        ..., help="Image of a ColorChecker 24: raw (DNG...), EXR, or 8-bit (with --response)."
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Profile JSON to write."),
    corners: str | None = typer.Option(
        None,
        "--corners",
        help="Centres of the corner patches x1,y1,...,x4,y4 in pixels: dark skin, bluish green, black, white.",
    ),
    response_path: Path | None = typer.Option(None, "--response", help="Response profile to linearise an 8-bit image."),
    white_preserving: bool = typer.Option(
        True, "--white-preserving/--free", help="Constrain the CCM to map white exactly."
    ),
    objective: str = typer.Option(
        "delta-e", "--objective", help="delta-e (least squares refined on CIEDE2000) or linear."
    ),
    as_json: bool = JSON,
) -> None:
    """White balance + 3x3 colour-correction matrix from a ColorChecker (CIEDE2000 before/after)."""
    c = parse_floats(corners, "--corners", 8) if corners is not None else None
    resp = ResponseProfile.load(response_path).array() if response_path else None
    img = read_linear_image(image, resp)
    with status.status("locating the chart and fitting"):
        prof = calibrate_colour(
            img, None if c is None else np.array(c).reshape(4, 2), white_preserving, inputs=[image], objective=objective
        )
    prof.save(out)
    if as_json:
        _print_json(prof, out)
        return
    r = prof.residuals
    table = Table(title=f"colour profile ({prof.detection})", show_header=False)
    table.add_row("white balance (R, G, B)", ", ".join(f"{g:.4g}" for g in prof.white_balance))
    table.add_row("CCM", "\n".join("  ".join(f"{v:+.4f}" for v in row) for row in prof.ccm))
    for stage in ("before", "white_balance", "ccm_linear_lsq", "ccm"):
        table.add_row(
            f"CIEDE2000 {stage.replace('_', ' ')}",
            f"mean {r['ciede2000_mean'][stage]:.2f}, max {r['ciede2000_max'][stage]:.2f}",
        )
    table.add_row(
        "CIEDE2000 leave-one-patch-out",
        f"mean {r['ciede2000_leave_one_patch_out_mean']:.2f} (linear LSQ, each patch unseen)",
    )
    if r["patches_clipped"]:
        table.add_row("[yellow]clipped patches[/]", str(r["patches_clipped"]))
    table.add_row("profile", str(out))
    console.print(table)


# --------------------------------------------------------------------------------------- camera
@app.command()
def camera(
    inputs: list[Path] = typer.Argument(..., help="One photo (EXIF route) or checkerboard views (with --pattern)."),
    out: Path = typer.Option(..., "-o", "--out", help="Profile JSON to write."),
    pattern: str | None = typer.Option(
        None, "--pattern", help="Checkerboard inner corners COLSxROWS: calibrate from the views."
    ),
    charuco: str | None = typer.Option(
        None, "--charuco", help="ChArUco board squares COLSxROWS: calibrate from the views."
    ),
    square: float = typer.Option(1.0, "--square", help="Board square size (any unit)."),
    marker_ratio: float = typer.Option(0.7, "--marker-ratio", help="ChArUco marker side / square side."),
    dictionary: str = typer.Option("DICT_4X4_50", "--dictionary", help="ChArUco ArUco dictionary."),
    sensor_width_mm: float | None = typer.Option(None, "--sensor-width-mm", help="Sensor width (overrides the table)."),
    hfov_deg: float | None = typer.Option(None, "--hfov-deg", help="Known horizontal field of view in degrees."),
    as_json: bool = JSON,
) -> None:
    """Photo-camera intrinsics K (EXIF, field of view or checkerboard) and K at the model's 320x240 input."""
    if hfov_deg is not None:
        hfov_deg = parse_angle(hfov_deg, "--hfov-deg", 0.0, 180.0, open_interval=True)
    if pattern or charuco:
        with status.status(f"detecting the board in {len(inputs)} views"):
            prof = calibrate_camera_from_board(
                inputs, _target(pattern, charuco, square, marker_ratio, dictionary), square
            )
    else:
        if len(inputs) != 1:
            raise InputError("give one photo (EXIF route), or --pattern COLSxROWS for checkerboard views")
        prof = calibrate_camera_from_photo(inputs[0], sensor_width_mm, hfov_deg)
    prof.save(out)
    if as_json:
        _print_json(prof, out)
        return
    K, K2 = prof.matrix(), prof.matrix(True)
    table = Table(title=f"camera profile ({prof.source})", show_header=False)
    table.add_row(
        "image",
        f"{prof.image_size[0]} x {prof.image_size[1]}"
        + (f" ({escape(prof.camera_model)})" if prof.camera_model else ""),
    )
    table.add_row("fx, fy / cx, cy", f"{K[0, 0]:.2f}, {K[1, 1]:.2f} / {K[0, 2]:.2f}, {K[1, 2]:.2f} px")
    table.add_row("field of view", f"{prof.hfov_deg:.2f}° x {prof.vfov_deg:.2f}°")
    x0, y0, w, h = prof.crop_box
    table.add_row(
        "crop -> 320x240", f"{w}x{h} at ({x0}, {y0}); fx {K2[0, 0]:.2f}, cx, cy {K2[0, 2]:.2f}, {K2[1, 2]:.2f}"
    )
    if "rms_px" in prof.residuals:
        table.add_row("RMS reprojection", f"{prof.residuals['rms_px']:.3f} px ({prof.residuals['views_used']} views)")
        for name, why in prof.residuals["rejected_views"].items():
            table.add_row(f"[yellow]rejected[/] {escape(name)}", escape(why))
    table.add_row("profile", str(out))
    console.print(table)


# ----------------------------------------------------------------------------------------- lens
@app.command()
def lens(
    views: list[Path] = typer.Argument(..., help="Checkerboard views through the fisheye lens."),
    out: Path = typer.Option(
        ...,
        "-o",
        "--out",
        help="Lens profile JSON to write (lens-profile format); a .calibration.json record is written beside it.",
    ),
    pattern: str | None = typer.Option(None, "--pattern", help="Checkerboard inner corners COLSxROWS (e.g. 6x9)."),
    charuco: str | None = typer.Option(
        None, "--charuco", help="ChArUco board squares COLSxROWS (instead of --pattern)."
    ),
    square: float = typer.Option(1.0, "--square", help="Square size (any unit)."),
    marker_ratio: float = typer.Option(0.7, "--marker-ratio", help="ChArUco marker side / square side."),
    dictionary: str = typer.Option("DICT_4X4_50", "--dictionary", help="ChArUco ArUco dictionary."),
    name: str = typer.Option("front", "--name", help="Lens name in the profile (front, back, ...)."),
    model: str = typer.Option("auto", "--model", help="auto (lowest held-out error), kb or mei."),
    crop: str | None = typer.Option(
        None, "--crop", help="x0,y0,w,h: this lens' region of each view (dual-fisheye frames)."
    ),
    ypr: str = typer.Option("0,0,0", "--ypr", help="Lens orientation yaw,pitch,roll in degrees (back lens: 180,0,0)."),
    max_angle_deg: float | None = typer.Option(
        None, "--max-angle-deg", help="Largest incidence angle the lens images."
    ),
    holdout_k: int | None = typer.Option(None, "--holdout-k", help="Views held out per fold (default: 5 folds)."),
    add_to: Path | None = typer.Option(
        None, "--add-to", help="Existing lens profile to add this lens to (replaces a lens of the same name)."
    ),
    profile_name: str = typer.Option("calibrated", "--profile-name", help="Profile 'model' name."),
    camera_model: list[str] = typer.Option([], "--camera-model", help="EXIF camera model(s) the profile applies to."),
    max_blur_px: float = typer.Option(
        4.0, "--max-blur-px", help="Reject views whose board edges are wider than this (px)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the lens profile and the calibration record as JSON."),
) -> None:
    """Fisheye intrinsics (Kannala-Brandt and Mei) from checkerboard views, exported as a lens profile."""
    target = _target(pattern, charuco, square, marker_ratio, dictionary)
    base = load_lens_profile(add_to) if add_to else None  # a bad --add-to fails before the views are read
    pat = target if isinstance(target, tuple) else target.pattern
    models = ("kb", "mei") if model == "auto" else (model,)
    if model not in ("auto", "kb", "mei"):
        raise InputError(f"--model: auto, kb or mei, got {model!r}")
    box = parse_floats(crop, "--crop", 4) if crop is not None else None
    angles = parse_angles(ypr, "--ypr", 3)
    images, full_size = read_views(views, box)
    with status.status(f"detecting the board in {len(views)} views"):
        dviews = detect_views(images, target, max_blur_px, names=[p.name for p in views])
    with status.status("fitting " + " and ".join(models) + " with held-out folds"):
        cal = calibrate_fisheye(
            dviews,
            pat,
            square,
            cast("tuple[ModelName, ...]", models),
            holdout_k,
            name,  # checked above
            offset=(box[0], box[1]) if box else (0.0, 0.0),
            ypr_deg=cast("tuple[float, float, float]", tuple(angles)),
            max_angle_deg=max_angle_deg,
            inputs=views,
        )
    prof = lens_profile_from_calibrations([cal], profile_name, full_size, camera_model, base=base)
    prof.save(out)
    record = out.with_name(f"{out.stem}.{name}.calibration.json")
    cal.save(record)
    if as_json:
        _print_json(prof, out, record=str(record), calibration=cal.model_dump(mode="json"))
        return
    table = Table(title=f"lens {name}: {cal.chosen_model} ({escape(cal.choice_reason)})")
    table.add_column("view", overflow="fold")
    for m in cal.models:
        table.add_column(f"{m} fit px")
        table.add_column(f"{m} held-out px")
    for v in dviews:
        row = [escape(v.name)]
        for _, info in cal.models.items():
            if "error" in info:
                row += ["-", "-"]
                continue
            row += [_fmt(info["per_view_rms_px"].get(v.name)), _fmt(info["held_out"]["per_view_rms_px"].get(v.name))]
        if cal.views.get(v.name, "used") != "used":
            row[0] += f" [yellow]({escape(cal.views[v.name])})[/]"
        table.add_row(*row)
    summary = ["total"]
    for _, info in cal.models.items():
        summary += ["-", "-"] if "error" in info else [_fmt(info["rms_px"]), _fmt(info["held_out"]["rms_px"])]
    table.add_row(*summary, style="bold")
    console.print(table)
    for m, info in cal.models.items():
        if "error" in info:
            console.print(f"[yellow]{m} failed:[/] {escape(info['error'])}")
    lm = cal.lens_model()
    console.print(
        f"centre ({lm.center[0]:.2f}, {lm.center[1]:.2f}) px, f {lm.poly[0]:.2f} px/rad, max angle "
        f"{lm.max_angle_deg:.1f}° (board seen up to {cal.observed_max_angle_deg:.1f}°); wrote {out} and {record}"
    )
    for w in cal.warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")


# ----------------------------------------------------------------------------------- vignetting
@app.command()
def vignetting(
    image: Path = typer.Argument(
        ..., help="Linear(isable) fisheye image: a flat field, or a dual-fisheye scene (overlap)."
    ),
    out: Path = typer.Option(..., "-o", "--out", help="Profile JSON to write."),
    lens_profile: str = typer.Option(
        ..., "--lens-profile", help="Lens profile name (theta-s, ...) or JSON file: the geometry."
    ),
    method: str = typer.Option("overlap", "--method", help="overlap (two lenses) or flat (flat field)."),
    degree: int | None = typer.Option(
        None, "--degree", min=1, help="Polynomial terms in rho^2 (default: 1 overlap, 3 flat)."
    ),
    response_path: Path | None = typer.Option(None, "--response", help="Response profile to linearise an 8-bit image."),
    saturation: float = typer.Option(0.98, help="Linear value at/above which a pixel counts as clipped."),
    as_json: bool = JSON,
) -> None:
    """Radial falloff of each fisheye lens, from a flat field or the two lenses' overlap."""
    resp = ResponseProfile.load(response_path).array() if response_path else None
    img = read_linear_image(image, resp)
    h, w = img.shape[:2]
    lp = load_lens_profile(lens_profile).scaled(w, h)
    with status.status(f"fitting the falloff ({method})"):
        if method == "overlap":
            lenses, res = fit_overlap(img, lp, degree or 1, saturation=saturation)
        elif method == "flat":
            lenses, res = fit_flat_field(img, lenses_from_profile(lp), degree or 3, saturation=saturation)
        else:
            raise InputError(f"--method: overlap or flat, got {method!r}")
    prof = make_profile(
        "overlap" if method == "overlap" else "flat-field",
        lenses,
        (w, h),
        res,
        [image],
        lens_profile=lp,
        degree=degree,
        saturation=saturation,
    )
    prof.save(out)
    if as_json:
        _print_json(prof, out)
        return
    table = Table(title=f"vignetting ({prof.method})", show_header=False)
    for l in prof.lenses:
        table.add_row(
            l.name,
            "V = 1 "
            + " ".join(f"{a:+.4f}·ρ^{2 * (k + 1)}" for k, a in enumerate(l.coeffs))
            + f";  V(0.5) = {falloff(l.coeffs, 0.5):.3f}, V(0.9) = {falloff(l.coeffs, 0.9):.3f}",
        )
    if prof.method == "overlap":
        table.add_row("samples / ρ range", f"{res['samples']} / {res['rho_range'][0]:.3f}..{res['rho_range'][1]:.3f}")
        table.add_row("coefficient std. error", ", ".join(f"{e:.3g}" for e in res["coeff_stderr"]))
        table.add_row(
            "log ratio robust RMS",
            f"{res['log_ratio_robust_rms_stops_before']:.3f} -> {res['log_ratio_robust_rms_stops_after']:.3f} stops",
        )
        table.add_row("lens gain ratio (R, G, B)", ", ".join(f"{g:.4f}" for g in res["gain_ratio_per_channel"]))
    else:
        for name, r in res.items():
            table.add_row(f"{name} fit", f"RMS {r['rms_rel']:.2%} of the binned profile, {r['pixels']} pixels")
    table.add_row("profile", str(out))
    console.print(table)
    if prof.method == "overlap" and res["log_ratio_robust_rms_stops_after"] >= res["log_ratio_robust_rms_stops_before"]:
        console.print(
            "[yellow]warning:[/] the falloff did not reduce the overlap disagreement: this scene does not "
            "constrain it (parallax, texture, a non-linear image); prefer a flat field"
        )


@app.command()
def fisheye(
    frame: Path = typer.Argument(
        ...,
        help=(
            "One dual-fisheye frame (JPEG, PNG, DNG, EXR) of the camera: outdoors, with texture around the horizon, "
            "works best."
        ),
    ),
    out: Path = typer.Option(
        ..., "-o", "--out", help="Lens profile JSON to write (use with `capture unwarp --profile`)."
    ),
    family: str = typer.Option(
        "auto",
        "--family",
        help="Projection: auto (the best seam), equidistant, equisolid or theta (Ricoh's lens table).",
    ),
    refine: bool = typer.Option(
        True,
        "--refine/--no-refine",
        help="Refine centres, scales and the back lens on the overlap (refused when it does not lower the seam error).",
    ),
    name: str | None = typer.Option(None, "--name", help="Profile 'model' name (default: the frame's file name)."),
    max_back_tilt_deg: float = typer.Option(
        3.0,
        "--max-back-tilt-deg",
        help="How far (degrees) the back lens' axis may be from exactly opposite the front's (a rigid body: a few).",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """A starting lens profile for any dual-fisheye camera from one frame: image circles, layout, projection and field of view, then a robust overlap refinement."""  # noqa: E501
    if family != "auto" and family not in FAMILIES:
        raise InputError(f"--family: auto, {', '.join(FAMILIES)}; got {family!r}")
    families = FAMILIES if family == "auto" else (family,)
    if out.exists() and out.is_dir():
        raise InputError(f"{out}: is a folder; give the profile's file name (e.g. {out / 'unit.json'})")
    max_back_tilt_deg = parse_angle(max_back_tilt_deg, "--max-back-tilt-deg", 0.0, 30.0)
    _, s = fit_file(
        frame,
        out,
        families=families,
        refine=refine,
        name=name,
        max_back_tilt_deg=max_back_tilt_deg,
        log=lambda m: status.print(escape(m)),
    )
    if as_json:
        echo_json(s, default=str)
        return
    table = Table(title=escape(str(out)), show_header=False)
    table.add_row("frame", f"{escape(str(frame))} ({s['size'][0]} x {s['size'][1]})")
    table.add_row(
        "layout",
        f"{s['layout']} (up from {s['upright']['cue']}"
        + ("" if s["upright"]["confident"] else ", [yellow]not confident[/]")
        + ")",
    )
    table.add_row("image circles", "; ".join(f"({c['cx']:.1f}, {c['cy']:.1f}) r {c['r']:.1f} px" for c in s["circles"]))
    table.add_row(
        "projection / field of view",
        f"{s['family']} / {s['fov_deg']:.1f}°  ("
        + ", ".join(f"{k} {v['fov_deg']:.1f}°: {v['seam_error']:.3f}" for k, v in s["families"].items())
        + ")",
    )
    table.add_row("lens centres", "; ".join(f"({x:.2f}, {y:.2f})" for x, y in s["centers"]) + " px")
    table.add_row(
        "back lens ypr",
        ", ".join(f"{a:.2f}°" for a in s["back_ypr_deg"])
        + f" ({s['back_tilt_deg']:.2f}° off opposite; at most {s['max_back_tilt_deg']:g}°)",
    )
    d = s["seam_disparity"] or {}
    table.add_row(
        "seam disparity (the same scene point in both lenses)",
        "unmeasured (too few matches)"
        if d.get("median_deg") is None
        else f"median {d['median_deg']:.2f}°, 95 % within {d['p95_deg']:.2f}°, "
        f"{100 * d['doubled_fraction']:.0f} % over 1° ({d['matches']} matches, {100 * d['coverage']:.0f} % of "
        "the ring)",
    )
    refined = f"{s['seam_error_refined']:.3f}" if s["refinement"] else "-"
    table.add_row(
        "seam error (0 = perfect, ~0.6 = 4° off, 1 = unrelated)",
        f"start {s['seam_error_start']:.3f}, refined {refined}, kept {s['seam_error']:.3f}",
    )
    console.print(table)
    for w in s["warnings"]:
        console.print(f"[yellow]warning:[/] {escape(w)}")


@app.command()
def overlap(
    images: list[Path] = typer.Argument(
        ...,
        help=(
            "Dual-fisheye captures of one camera unit (same size; outdoor scenes with texture at the horizon work "
            "best)."
        ),
    ),
    base: str = typer.Option(
        ...,
        "--base",
        help="Model lens profile to start from (theta-v, theta-z1, theta-s, theta-s-video or a JSON file).",
    ),
    out: Path = typer.Option(
        ..., "-o", "--out", help="Per-unit lens profile to write (JSON; use with `capture unwarp --profile`)."
    ),
    circle_sigma: float = typer.Option(
        1.0,
        "--circle-sigma",
        help="Prior (px) tying each lens centre to its fitted image circle; 0 = photometric only.",
    ),
    scale_sigma: float = typer.Option(
        0.005, "--scale-sigma", help="Prior std of the difference of the two lenses' log scales."
    ),
    fix_scale: bool = typer.Option(False, "--fix-scale", help="Keep r(theta) as in the base profile."),
    as_json: bool = typer.Option(False, "--json", help="Print the refinement summary as JSON."),
) -> None:
    """Refine lens centres, scales and the inter-lens rotation on the overlap ring (robust photometric fit)."""
    s = refine_files(
        images, base, out, circle_sigma_px=circle_sigma or None, scale_sigma=scale_sigma, fix_scale=fix_scale
    )
    if as_json:
        echo_json(s, default=str)
        return
    table = Table(title=escape(str(out)), show_header=False)
    table.add_row("base profile / images", f"{escape(s['base'])} / {s['images']}")
    for i, name in enumerate(("front", "back")):
        dx, dy = s["center_shift_px"][i]
        table.add_row(f"{name} centre shift / scale", f"{dx:+.2f}, {dy:+.2f} px / {s['scale'][i]:.4f}")
    table.add_row(
        "back lens rotation change",
        f"{s['back_rotation_change_deg']:.3f}° (ypr now " + ", ".join(f"{a:.2f}°" for a in s["back_ypr_deg"]) + ")",
    )
    table.add_row(
        "seam error",
        f"{s['seam_error_before']:.3f} -> {s['seam_error_after']:.3f}"
        + (" [yellow](refused)[/]" if s["refused"] else ""),
    )
    table.add_row("seam disagreement (linear)", f"{s['seam_mad_before']:.4g} -> {s['seam_mad_after']:.4g}")
    console.print(table)
    for w in s["warnings"]:
        console.print(f"[yellow]warning:[/] {escape(w)}")
