"""``solidkit demo``: the end-to-end path that works today, on a shipped real HDR panorama.

Steps (each writes its product into ``OUT`` and a line into ``summary.json``):

1. read a real outdoor HDR panorama (Poly Haven ``city.exr``, CC0, shipped in ``solidkit/assets``);
2. find the sun with the default (``core``) and the paper's method, and their disagreement;
3. shoot a virtual limited-FOV photo (320x240, 60° horizontal FOV, pitch 5°) facing away from
   the sun, as SOLID-Net's input would be, and embed it back into the panorama frame;
4. resize to the model's 256x128 with the energy-preserving resampler (integral kept);
5. project onto the paper's second-order SH basis and compare the diffuse convolution D(H)
   with the SH prediction (the quantity the paper's L_dif ties together);
6. run the shipped SOLID-Net checkpoint on the virtual photo (its LDR = the paper's tonemap) at
   two ground pixels: predicted global sky, its sun and two local probes, with the sun's angular
   error against the panorama's own sun (the shipped checkpoint is smoke-level: see its card);
7. a report figure (``report.png``) with the tonemapped panorama, sun markers, photo and D(H).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.envmap.coords import angular_distance, rotation_from_ypr, solid_angle
from solidkit.envmap.io import read_image, tonemap, validate_panorama, write_exr, write_ldr
from solidkit.envmap.perspective import embed_perspective, intrinsics_from_fov, perspective_crop
from solidkit.envmap.resample import resize
from solidkit.envmap.sh import diffuse_convolution, lambertian_sphere, sh_irradiance, sh_project
from solidkit.envmap.sun import detect_sun
from solidkit.fsutil import atomic_path, atomic_write_text

DEFAULT_PANORAMA = Path(__file__).parent / "assets" / "hdr_panoramas" / "city.exr"
PHOTO_SIZE = (320, 240)
PHOTO_FOV_DEG = 60.0
PHOTO_PITCH_DEG = 5.0
MODEL_HEIGHT = 128


def _integral(pano: np.ndarray) -> np.ndarray:
    return (pano * solid_angle(pano.shape[0])[..., None]).sum(axis=(0, 1))


def run_demo(out: Path, pano_path: Path = DEFAULT_PANORAMA, log: Any = print) -> dict[str, Any]:
    """Run the demo into ``out``; returns the summary (also written to ``out/summary.json``)."""
    pano, _ = read_image(pano_path)
    validate_panorama(pano, str(pano_path))
    out.mkdir(parents=True, exist_ok=True)  # only once the input is known to be good
    summary: dict[str, Any] = {"panorama": str(pano_path), "size": [pano.shape[1], pano.shape[0]]}
    log(f"panorama {pano_path.name}: {pano.shape[1]}x{pano.shape[0]}, max {pano.max():.4g}")

    core, paper = detect_sun(pano, "core"), detect_sun(pano, "paper")
    summary["sun"] = {"core": core.to_json(), "paper": paper.to_json()}
    if core.found and paper.found:
        summary["sun"]["paper_vs_core_deg"] = math.degrees(float(angular_distance(core.direction, paper.direction)))
    log(f"sun (core): {json.dumps(core.to_json())}")
    log(f"sun (paper): {json.dumps(paper.to_json())}")

    yaw = (core.azimuth + math.pi) if core.found else 0.0
    R = rotation_from_ypr(yaw, math.radians(PHOTO_PITCH_DEG), 0.0)
    K = intrinsics_from_fov(math.radians(PHOTO_FOV_DEG), *PHOTO_SIZE)
    photo = perspective_crop(pano, R, PHOTO_SIZE, K=K)
    write_exr(out / "photo.exr", photo, {"K": K.tolist(), "yaw_deg": math.degrees(yaw), "pitch_deg": PHOTO_PITCH_DEG})
    write_ldr(out / "photo.png", tonemap(photo))
    embedded, mask = embed_perspective(photo, K, R, MODEL_HEIGHT * 2)
    write_ldr(out / "photo_in_panorama.png", tonemap(embedded))
    summary["photo"] = {"size": list(PHOTO_SIZE), "fov_deg": PHOTO_FOV_DEG, "yaw_deg": math.degrees(yaw),
                        "pitch_deg": PHOTO_PITCH_DEG, "panorama_coverage": float(np.mean(mask))}
    log(f"photo 320x240 facing azimuth {math.degrees(yaw):.1f}°, covers {100 * np.mean(mask):.1f}% of the sphere")

    small = resize(pano, MODEL_HEIGHT)
    write_exr(out / "panorama_256x128.exr", small)
    write_ldr(out / "panorama_256x128.png", tonemap(small))
    i_full, i_small = _integral(pano), _integral(small)
    summary["resize"] = {"integral_full": i_full.tolist(), "integral_256x128": i_small.tolist(),
                         "max_rel_error": float(np.max(np.abs(i_small / i_full - 1)))}
    log(f"energy-preserving resize to 256x128: integral rel. error {summary['resize']['max_rel_error']:.2e}")

    L = sh_project(small)
    D = diffuse_convolution(small)
    D_sh = lambertian_sphere(sh_irradiance(L), MODEL_HEIGHT)
    write_exr(out / "diffuse_convolution.exr", D)
    rel = float(np.mean(np.abs(D_sh - D)) / np.mean(np.abs(D)))
    summary["sh"] = {"coefficients": np.asarray(L).tolist(), "D_vs_sh_mean_rel_error": rel}
    log(f"diffuse convolution D(H) vs order-2 SH prediction: mean rel. error {rel:.3f}")

    summary["model"] = _predict(out, tonemap(photo), K, yaw, core, log)
    predicted_sky, _ = read_image(out / "predicted_sky.exr")

    _figure(out / "report.png", small, core, paper, photo, D, predicted_sky)
    summary["outputs"] = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
    log(f"wrote {len(summary['outputs']) + 1} files to {out}")
    return summary


def _predict(out: Path, ldr: np.ndarray, K: np.ndarray, yaw: float, sun: Any, log: Any) -> dict[str, Any]:
    from solidkit.model import SolidNet

    net = SolidNet.from_checkpoint()
    w, h = PHOTO_SIZE
    pixels = [(w * 0.3, h * 0.85), (w * 0.7, h * 0.85)]
    pred = net.predict(ldr, pixels, K=K, pitch=math.radians(PHOTO_PITCH_DEG))
    write_exr(out / "predicted_sky.exr", pred.sky)
    write_ldr(out / "predicted_sky.png", tonemap(pred.sky))
    for i, local in enumerate(pred.local):
        write_exr(out / f"predicted_local_{i}.exr", local)
        write_ldr(out / f"predicted_local_{i}.png", tonemap(local))
    result: dict[str, Any] = {"pixels": [list(p) for p in pixels], "sun": pred.sun.to_json()}
    if sun.found and pred.sun.found:
        # the photo's panorama frame is the original one turned by the photo's yaw
        truth = rotation_from_ypr(yaw).T @ sun.direction
        result["sun_error_deg"] = math.degrees(float(angular_distance(truth, pred.sun.direction)))
    log(f"SOLID-Net (shipped smoke-level checkpoint): sun {json.dumps(pred.sun.to_json())}"
        + (f", error {result['sun_error_deg']:.1f}°" if "sun_error_deg" in result else ""))
    return result


def _figure(
    path: Path, pano: np.ndarray, core: Any, paper: Any, photo: np.ndarray, D: np.ndarray, sky: np.ndarray
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h = pano.shape[0]
    fig, axes = plt.subplots(2, 2, figsize=(12, 6.4))
    axes = axes.ravel()
    axes[0].imshow(tonemap(pano), extent=(-180, 180, -90, 90))
    for det, colour, name in ((core, "lime", "core"), (paper, "magenta", "paper")):
        if det.found:
            axes[0].plot(det.azimuth_deg, det.elevation_deg, "*", ms=14, mfc="none", mec=colour, label=f"sun ({name})")
    axes[0].set(title=f"panorama {2 * h}x{h} (tonemap e=-0.3)", xlabel="azimuth [°]", ylabel="elevation [°]")
    axes[0].legend(loc="lower left", fontsize=8)
    axes[1].imshow(tonemap(photo))
    axes[1].set(title="virtual 320x240 photo", xticks=[], yticks=[])
    axes[2].imshow(tonemap(D / max(float(D.max()), 1e-12)), extent=(-180, 180, -90, 90))
    axes[2].set(title="diffuse convolution D(H) (normalised)", xlabel="azimuth [°]")
    axes[3].imshow(tonemap(sky), extent=(-180, 180, -90, 90))
    axes[3].set(title="SOLID-Net sky from the photo (shipped smoke-level checkpoint)", xlabel="azimuth [°]")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
