"""Crops for the sun stage of training: thousands of small panoramas in memory, sun targets looked up.

The crop path of I-Net (:class:`solidkit.synth.panocrops.CropSampler`) reads each source from disk or
a bounded cache, rotates the whole lighting target for every crop and runs the sun detector on it:
~15-20 ms a crop, as much as :class:`solidkit.model.sunnet.SunNet` needs for a training step on it.
:class:`SunCropBank` keeps every source at ``BANK_HEIGHT`` (float16, 0.75 MB each) and measures the
sun of its lighting once, in the scene frame (direction, visibility, energy, angular size: all
rotation-invariant but the direction, which a crop's yaw and flip turn analytically). A crop then
costs one ``192 x 256`` resampling (~2 ms).

Targets follow :class:`~solidkit.synth.panocrops.CropSampler`: the camera's panorama frame is the
scene turned by the crop's yaw (``d_cam = R_y(yaw)^T d_scene``), a horizontal flip negates ``x``, and
the energy is scaled by the exposure x white-balance gain applied to the image.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from solidkit.envmap.resample import downsample
from solidkit.envmap.sun import detect_sun
from solidkit.errors import InputError
from solidkit.synth.panocrops import draw_view, render_view, view_direction
from solidkit.synth.sample import derive_seed

__all__ = ["BANK_HEIGHT", "CROP_SIZE", "SourceSun", "SunCropBank", "source_sun"]

BANK_HEIGHT = 256
"""Height of the panoramas kept in memory (a 60° crop of 256 px then sees ~85 px across)."""
CROP_SIZE = (192, 256)
"""``(H, W)`` of a sun-stage crop; :class:`~solidkit.model.sunnet.SunNet` resizes it to its own size."""


@dataclass(frozen=True)
class SourceSun:
    """The sun of a source's lighting, scene frame: unit ``direction (3,)``, ``visible``, ``energy (3,)``
    (radiance x sr, :func:`solidkit.model.losses.sun_energy`) and ``size`` (radians,
    :func:`solidkit.model.losses.sun_size`); direction zero and energy zero where no sun is visible."""

    direction: np.ndarray
    visible: bool
    energy: np.ndarray
    size: float


def source_sun(light: np.ndarray, known: Any = None) -> SourceSun:
    """:class:`SourceSun` of a lighting panorama ``light (h, 2h, 3)``: the crop targets' detector
    (:func:`solidkit.envmap.detect_sun`), or ``known`` (a :class:`solidkit.synth.panocrops.CatalogSun`:
    visibility and direction measured independently) with energy and size measured at its direction."""
    from solidkit.model.losses import sun_energy, sun_size  # lazy: pulls in kornia

    if known is not None:
        found, direction = bool(known.visible), np.asarray(known.direction, np.float64)
    else:
        sun = detect_sun(light)
        found, direction = sun.found, np.asarray(sun.direction if sun.found else np.zeros(3))
    if not found:
        return SourceSun(np.zeros(3, np.float32), False, np.zeros(3, np.float32), 0.0)
    sky = torch.as_tensor(np.ascontiguousarray(light), dtype=torch.float32).permute(2, 0, 1)[None]
    d = torch.as_tensor(direction, dtype=torch.float32)[None]
    return SourceSun(direction.astype(np.float32), True, sun_energy(sky, d)[0].numpy(), float(sun_size(sky, d)[0]))


class SunCropBank:
    """Sources held in memory at ``height`` with their :class:`SourceSun`; batches of crops with sun targets.

    ``add(name, source)`` takes a :class:`solidkit.synth.panocrops.Source`; ``batch(seed, step, size, config)``
    is a pure function of its arguments and of the bank's names (resumable training).
    """

    def __init__(self, height: int = BANK_HEIGHT) -> None:
        self.height = int(height)
        self.names: list[str] = []
        self._index: dict[str, int] = {}
        self._panos: list[np.ndarray] = []
        self._suns: list[SourceSun] = []
        self.weights: np.ndarray | None = None
        """Probability of drawing each held source (in the order of :attr:`names`); ``None``: uniform."""

    def __len__(self) -> int:
        return len(self.names)

    def add(self, name: str, source: Any) -> None:
        """Keep ``source`` (a ``panocrops.Source``) under ``name``; a name already held is left as it is."""
        if name in self._index:
            return
        scene, light = source.load()
        h = scene.shape[0]
        if h > self.height:
            if h % self.height:
                raise InputError(f"{name}: panorama height {h} is not a multiple of {self.height}")
            scene = downsample(scene, h // self.height)
        self._index[name] = len(self.names)
        self.names.append(name)
        self._panos.append(np.minimum(scene, 6.0e4).astype(np.float16))
        self._suns.append(source_sun(light, getattr(source, "sun", None)))

    def sync(self, names: list[str], sources: list[Any]) -> None:
        """Add every ``(name, source)`` not held yet; the bank's order is that of ``names`` afterwards."""
        for n, s in zip(names, sources):
            self.add(n, s)
        order = [self._index[n] for n in names]
        self.names = list(names)
        self._panos = [self._panos[i] for i in order]
        self._suns = [self._suns[i] for i in order]
        self._index = {n: i for i, n in enumerate(self.names)}

    def sun(self, name: str) -> SourceSun:
        """The :class:`SourceSun` of the source held under ``name``."""
        return self._suns[self._index[name]]

    def crop(self, rng: np.random.Generator, config: Any) -> dict[str, Any]:
        """One crop drawn with ``rng`` (ranges of a :class:`solidkit.synth.panocrops.CropConfig`)."""
        k = int(rng.integers(len(self.names)) if self.weights is None else rng.choice(len(self.names), p=self.weights))
        view = draw_view(rng, config)
        image, K, roll, gain = render_view(self._panos[k].astype(np.float32), view, config)
        sun = self._suns[k]
        d = view_direction(sun.direction, view)
        return {
            "image": image,
            "K": K,
            "pitch": np.float32(view.pitch),
            "roll": np.float32(roll),
            "yaw": np.float32(view.yaw),
            "sun_dir": (d if sun.visible else np.zeros(3)).astype(np.float32),
            "sun_visible": np.float32(sun.visible),
            "sun_energy": (sun.energy * gain).astype(np.float32),
            "sun_size": np.float32(sun.size),
            "source": self.names[k],
            "flip": view.flip,
        }

    def batch(
        self, seed: int, step: int, size: int, config: Any, rank: int = 0, world: int = 1
    ) -> dict[str, torch.Tensor]:
        """``size`` crops (this rank's share) collated: ``image (B, 3, H, W)``, ``K``, ``pitch``, ``roll``,
        ``sun_dir (B, 3)``, ``sun_visible``, ``sun_energy (B, 3)``, ``sun_size``."""
        if not self.names:
            raise InputError("the sun stage has no panoramas to crop")
        c = replace(config, height=CROP_SIZE[0], width=CROP_SIZE[1])
        seeds = np.random.default_rng(derive_seed(seed, 13, step)).integers(0, 2**31 - 1, size)[rank::world]
        items = [self.crop(np.random.default_rng(int(s)), c) for s in seeds]
        t = lambda key: torch.as_tensor(np.stack([it[key] for it in items]), dtype=torch.float32)  # noqa: E731
        return {
            "image": t("image").permute(0, 3, 1, 2).contiguous(),
            "K": t("K"),
            "pitch": t("pitch"),
            "roll": t("roll"),
            "sun_dir": t("sun_dir"),
            "sun_visible": t("sun_visible"),
            "sun_energy": t("sun_energy"),
            "sun_size": t("sun_size"),
        }
