"""A torch ``Dataset`` over a test set (``testset.json``), with the keys of the synthetic dataset.

Keys shared with :class:`solidkit.synth.dataset.SynthDataset` keep its meaning, shapes and units:
``image``, ``probes`` (HDR radiance), ``probe_pixels``, ``probe_valid``, ``global``, ``sun``,
``sun_found``, ``K``, ``pitch``, ``roll``, ``index``. A real scene has a variable number of probes,
so probe tensors are padded to ``max_probes`` (default: the most in the set) and ``probe_valid``
marks the real ones; ``probes`` is zero where a probe has no HDR bracket (``probe_hdr_valid``).
The real set's ground truth of the paper is the LDR probe: ``probes_ldr`` with ``saturation``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch.utils.data

from solidkit.envmap.io import imread, read_exr, read_ldr
from solidkit.errors import InputError
from solidkit.synth.dataset import chw_tensor
from solidkit.testset.build import load_testset
from solidkit.testset.schema import PROBE_SIZE

__all__ = ["TestsetDataset"]


class TestsetDataset(torch.utils.data.Dataset):
    """A torch ``Dataset`` over a test set folder (reads ``testset.json``); one item per scene.

    Each item is a dict: ``image`` (3, 240, 320) the sRGB photo in [0, 1]; ``probes``
    (P, 3, 128, 256) HDR probes (linear, relative units; zeros without a bracket), ``probes_ldr``
    (P, 3, 128, 256) sRGB LDR probes in [0, 1], ``saturation`` (P, 1, 128, 256) 1 where the LDR
    probe is clipped, ``probe_pixels`` (P, 2) ``(x, y)`` in the 320x240 photo, ``probe_valid`` (P,),
    ``probe_hdr_valid`` (P,); ``global`` (3, 128, 256) HDR of the capture at the camera position
    (zeros when absent; ``global_valid``); ``sun`` (3,) unit direction in the photo's panorama
    frame (zeros if no sun), ``sun_found`` (), ``sun_uncertainty_deg`` () degrees (NaN if unknown);
    ``K`` (3, 3), ``pitch``, ``roll`` (radians); ``index`` (int), ``scene`` (str), ``probe_ids``
    (list of str, padded with "").

    Parameters
    ----------
    root : path
        The test set folder.
    fields : iterable of str, optional
        Image fields to read among :attr:`ALL` (the others are skipped; geometry is always there).
    scenes : iterable of str, optional
        Only these scene ids (e.g. one fold of a k-fold split).
    max_probes : int, optional
        Pad/limit probes to this many (default: the largest count in the set).
    """

    ALL = ("image", "probes", "probes_ldr", "saturation", "global")
    __test__ = False

    def __init__(
        self,
        root: str | os.PathLike,
        *,
        fields: Iterable[str] | None = None,
        scenes: Iterable[str] | None = None,
        max_probes: int | None = None,
    ) -> None:
        self.root = Path(root)
        self.testset = load_testset(self.root)
        self.scenes = list(self.testset.scenes)
        if scenes is not None:
            wanted = list(scenes)
            known = {s.id for s in self.scenes}
            unknown = [s for s in wanted if s not in known]
            if unknown:
                raise InputError(f"{self.root}: no scene(s) {', '.join(unknown)}")
            self.scenes = [s for s in self.scenes if s.id in set(wanted)]
        self.fields = tuple(fields) if fields is not None else self.ALL
        bad = set(self.fields) - set(self.ALL)
        if bad:
            raise InputError(f"unknown fields {sorted(bad)}; choose from {self.ALL}")
        self.max_probes = (
            int(max_probes) if max_probes is not None else max((len(s.probes) for s in self.scenes), default=0)
        )
        self.dataset_version = self.testset.dataset_version

    def __len__(self) -> int:
        return len(self.scenes)

    def __getitem__(self, i: int) -> dict[str, Any]:
        import torch

        s = self.scenes[i]
        P, (w, h) = self.max_probes, PROBE_SIZE
        probes = s.probes[:P]
        item: dict[str, Any] = {
            "index": i,
            "scene": s.id,
            "probe_ids": [p.id for p in probes] + [""] * (P - len(probes)),
        }
        if "image" in self.fields:
            item["image"] = chw_tensor(read_ldr(self.root / s.photo))
        hdr_valid = np.zeros(P, np.float32)
        if "probes" in self.fields:
            stack = torch.zeros(P, 3, h, w)
            for k, p in enumerate(probes):
                if p.hdr is not None:
                    stack[k] = chw_tensor(read_exr(self.root / p.hdr)[0][..., :3])
            item["probes"] = stack
        for k, p in enumerate(probes):
            hdr_valid[k] = float(p.hdr is not None)
        if "probes_ldr" in self.fields:
            stack = torch.zeros(P, 3, h, w)
            for k, p in enumerate(probes):
                stack[k] = chw_tensor(read_ldr(self.root / p.ldr))
            item["probes_ldr"] = stack
        if "saturation" in self.fields:
            stack = torch.zeros(P, 1, h, w)
            for k, p in enumerate(probes):
                m = imread(self.root / p.images.saturation)
                stack[k] = chw_tensor((m if m.ndim == 2 else m[..., 0]) > 0)
            item["saturation"] = stack
        if "global" in self.fields:
            g = s.camera.images.hdr if s.camera is not None else None
            item["global"] = chw_tensor(read_exr(self.root / g)[0][..., :3]) if g else torch.zeros(3, h, w)
            item["global_valid"] = torch.tensor(float(g is not None))
        pix = np.zeros((P, 2), np.float32)
        valid = np.zeros(P, np.float32)
        for k, p in enumerate(probes):
            pix[k] = p.pixel
            valid[k] = 1.0
        item["probe_pixels"] = torch.from_numpy(pix)
        item["probe_valid"] = torch.from_numpy(valid)
        item["probe_hdr_valid"] = torch.from_numpy(hdr_valid)
        sun = s.sun
        item["sun"] = torch.tensor(
            sun.direction if sun.found and sun.direction else [0.0, 0.0, 0.0], dtype=torch.float32
        )
        item["sun_found"] = torch.tensor(float(sun.found))
        item["sun_uncertainty_deg"] = torch.tensor(float("nan") if sun.uncertainty_deg is None else sun.uncertainty_deg)
        item["K"] = torch.tensor(s.K, dtype=torch.float32)
        item["pitch"] = torch.tensor(math.radians(s.pitch_deg), dtype=torch.float32)
        item["roll"] = torch.tensor(math.radians(s.roll_deg), dtype=torch.float32)
        return item
