"""``solidkit predict IMAGE --at X,Y [--at X,Y ...] -o DIR``: SOLID-Net inference on one photo.

Writes, into DIR: ``sky.exr`` (the global HDR sky H_g) and ``local_NN.exr`` (one local HDR
panorama H_l per ``--at`` pixel), each with a tonemapped PNG beside it (the paper's tonemap,
e = -0.3), and ``prediction.json`` with the sun direction found in H_g (degrees, panorama frame of
docs/conventions.md) and each probe's pixel and 3D centre; ``--json`` prints that report on stdout.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from solidkit.cli.output import echo_json
from solidkit.cli.parsing import output_folder, parse_angle, parse_floats, parse_pixel
from solidkit.envmap.coords import CONVENTIONS_VERSION
from solidkit.envmap.io import read_ldr, tonemap, write_exr, write_ldr
from solidkit.envmap.perspective import intrinsics_from_fov
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_text

__all__ = ["predict_command"]

console = Console()


def _intrinsics(text: str | None) -> np.ndarray | None:
    if text is None:
        return None
    fx, fy, cx, cy = parse_floats(text, "--intrinsics", 4)
    if fx <= 0 or fy <= 0:
        raise InputError(f"--intrinsics: focal lengths fx, fy must be positive pixels, got {text!r}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def predict_command(
    image: Path = typer.Argument(..., help="Limited-FOV LDR photo (JPEG/PNG)."),
    at: list[str] = typer.Option(..., "--at", help="Probe pixel X,Y in IMAGE (repeatable)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output folder (created)."),
    checkpoint: Path | None = typer.Option(None, help="SOLID-Net checkpoint (default: the shipped one)."),
    hfov_deg: float | None = typer.Option(
        None, "--hfov-deg", help="Horizontal field of view of IMAGE in degrees (default: the checkpoint's)."
    ),
    intrinsics: str | None = typer.Option(None, help="fx,fy,cx,cy of IMAGE in pixels (overrides --hfov-deg)."),
    pitch: float = typer.Option(0.0, help="Camera pitch in degrees (positive = looking up)."),
    roll: float = typer.Option(0.0, help="Camera roll in degrees (positive = right side down)."),
    encoding: str = typer.Option(
        "srgb",
        "--encoding",
        help="How IMAGE encodes light: srgb (a camera's JPEG) or paper (an image made by the paper's tonemap).",
    ),
    response: Path | None = typer.Option(
        None,
        "--response",
        help="The camera's inverse response (a 'solidkit calibrate response' profile or a 256x3 curve): "
        "IMAGE is linearised through it (overrides --encoding).",
    ),
    as_json: bool = typer.Option(False, "--json", help="Print prediction.json on stdout instead of the summary."),
) -> None:
    """Predict the global HDR sky, its sun direction and a local HDR panorama at each --at pixel."""
    from solidkit.model.blocks import HDR_PARAMETERISATION  # lazy: solidkit.model imports torch (seconds), so
    from solidkit.model.solidnet import SolidNet  # only `solidkit predict` pays for it, not every command

    output_folder(out)
    pixels = [parse_pixel(a, "--at") for a in at]
    pitch, roll = parse_angle(pitch, "--pitch", -90.0, 90.0), parse_angle(roll, "--roll", -180.0, 180.0)
    if hfov_deg is not None:
        hfov_deg = parse_angle(hfov_deg, "--hfov-deg", 1.0, 179.0, open_interval=True)
    K = _intrinsics(intrinsics)
    if encoding not in ("srgb", "paper"):
        raise InputError(f"--encoding must be srgb or paper, got {encoding!r}")
    decoding: str | np.ndarray = encoding
    if response is not None:
        from solidkit.capture.frame_merge import load_response

        decoding = load_response(response)
    photo = read_ldr(image)
    model = SolidNet.from_checkpoint(checkpoint)
    if K is None and hfov_deg is not None:
        K = intrinsics_from_fov(math.radians(hfov_deg), photo.shape[1], photo.shape[0])
    pred = model.predict(photo, pixels, K=K, pitch=math.radians(pitch), roll=math.radians(roll), encoding=decoding)
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "source": str(image),
        "hdr_parameterisation": HDR_PARAMETERISATION,
        "model": model.config.name,
        "photo_encoding": "response " + str(response) if response is not None else encoding,
    }
    write_exr(out / "sky.exr", pred.sky, {**meta, "kind": "global sky H_g"})
    write_ldr(out / "sky.png", tonemap(pred.sky))
    probes: list[dict[str, Any]] = []
    for i, (local, px, centre, ok) in enumerate(zip(pred.local, pred.pixels, pred.centres, pred.extra["probe_valid"])):
        name = f"local_{i:02d}"
        write_exr(out / f"{name}.exr", local, {**meta, "kind": "local H_l", "pixel": px.tolist()})
        write_ldr(out / f"{name}.png", tonemap(local))
        probes.append(
            {
                "pixel": [float(px[0]), float(px[1])],
                "centre_m": [round(float(c), 4) for c in centre],
                "geometry_valid": bool(ok),
                "exr": f"{name}.exr",
                "png": f"{name}.png",
            }
        )
    report = {
        "image": str(image),
        "checkpoint": str(checkpoint) if checkpoint else "shipped",
        "conventions_version": CONVENTIONS_VERSION,
        "pitch_deg": pitch,
        "roll_deg": roll,
        "photo_encoding": meta["photo_encoding"],
        "sun": pred.sun.to_json(),
        **({"sun_network": pred.extra["sun_network"]} if "sun_network" in pred.extra else {}),
        "sky": {"exr": "sky.exr", "png": "sky.png"},
        "probes": probes,
    }
    atomic_write_text(out / "prediction.json", json.dumps(report, indent=2) + "\n")
    if as_json:
        echo_json({**report, "output": str(out)})
        return
    table = Table(title=f"SOLID-Net prediction -> {out}", show_header=False)
    sun = report["sun"]
    table.add_row(
        "sun",
        f"azimuth {sun['azimuth_deg']:.1f}°, elevation {sun['elevation_deg']:.1f}° (confidence {sun['confidence']:.2f})"
        if sun["found"]
        else "not found",
    )
    net = report.get("sun_network")
    if net and "cone_68_deg" in net:
        table.add_row(
            "sun network",
            f"azimuth {net['azimuth_deg']:.1f}°, elevation {net['elevation_deg']:.1f}°, "
            f"{'sun' if net.get('says_sun') else 'no sun'} (p = {net.get('visible_prob', float('nan')):.2f}), "
            f"68 % / 90 % cones {net['cone_68_deg']:.0f}° / {net['cone_90_deg']:.0f}°"
            f"{'' if net['cones_calibrated'] else ' (uncalibrated)'}"
            f"{', on the clipped sun in the photo' if net.get('in_image_blob') else ''}",
        )
    for p in probes:
        table.add_row(p["exr"], f"pixel ({p['pixel'][0]:g}, {p['pixel'][1]:g}), centre {p['centre_m']} m")
    console.print(table)
