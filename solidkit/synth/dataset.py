"""Sharded, resumable generation of a SOLID-Img-style dataset, its index, and a torch Dataset.

Layout of a dataset folder::

    dataset.json                 master seed, n, renderer config (fixed at creation)
    samples/000123/              one folder per sample (see solidkit.synth.sample.FILES);
                                 complete iff sample.json exists (written last, atomically)
    index.json                   every complete sample: folder, sun, lighting, filter score, keep

Shard ``i/N`` renders the contiguous index range ``[i n / N, (i + 1) n / N)`` (blocks of six
views stay together), so a Slurm array, Ray or Kubernetes job can run one shard per task
(``--shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT``). Re-running skips complete samples.
Each shard refreshes ``index.json`` when it ends (a scan of all complete samples).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch.utils.data

from solidkit.envmap import CONVENTIONS_VERSION, read_exr, read_ldr
from solidkit.errors import ConventionsError, InputError
from solidkit.fsutil import atomic_write_text
from solidkit.synth.filter import ReferenceSet
from solidkit.synth.sample import FILES, Generator, SampleConfig

__all__ = [
    "parse_shard",
    "shard_range",
    "open_dataset",
    "generate",
    "build_index",
    "rescore",
    "SynthDataset",
    "chw_tensor",
]

INDEX = "index.json"
MANIFEST = "dataset.json"


def parse_shard(text: str | None) -> tuple[int, int]:
    """``"i/N"`` -> ``(i, N)`` with ``0 <= i < N``; None -> ``(0, 1)``."""
    if not text:
        return 0, 1
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise InputError(f"--shard must look like i/N (e.g. 0/4), got '{text}'") from None
    if n < 1 or not 0 <= i < n:
        raise InputError(f"--shard {text}: need 0 <= i < N")
    return i, n


def shard_range(n: int, shard: int, shards: int) -> range:
    """Contiguous indices of shard ``shard`` of ``shards`` among ``n`` samples."""
    return range(shard * n // shards, (shard + 1) * n // shards)


def sample_dir(root: Path, index: int) -> Path:
    return root / "samples" / f"{index:06d}"


def open_dataset(root: str | os.PathLike, n: int, seed: int, config: SampleConfig) -> dict[str, Any]:
    """Create ``dataset.json`` or check that an existing one has the same seed and config."""
    root = Path(root)
    manifest = {
        "n": int(n),
        "seed": int(seed),
        "config": config.to_json(),
        "conventions_version": CONVENTIONS_VERSION,
        "generator": "solidkit synth dataset",
    }
    path = root / MANIFEST
    if path.is_file():
        old = json.loads(path.read_text())
        if old.get("seed") != manifest["seed"]:
            raise InputError(f"{root}: holds a dataset with seed {old.get('seed')}, not {seed}; use a new --out")
        if old.get("config") != manifest["config"]:
            oc, nc = old.get("config") or {}, manifest["config"]
            diff = sorted(k for k in set(oc) | set(nc) if oc.get(k) != nc.get(k))
            raise InputError(
                f"{root}: holds a dataset rendered with other settings ({', '.join(diff)}); use a new --out"
            )
        if int(old.get("n", 0)) < n:
            old["n"] = int(n)
            atomic_write_text(path, json.dumps(old, indent=1))
        return old
    root.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(manifest, indent=1))
    return manifest


def generate(
    root: str | os.PathLike,
    n: int,
    *,
    seed: int = 0,
    shard: tuple[int, int] = (0, 1),
    config: SampleConfig | None = None,
    reference: ReferenceSet | None = None,
    threshold: float = 0.7,
    progress: Callable[[int, int, dict[str, Any] | None], None] | None = None,
) -> dict[str, int]:
    """Render the missing samples of one shard; returns counts ``{"rendered", "skipped", "kept"}``.

    ``reference``: real photographs; each new sample gets ``filter.score`` and ``filter.keep``
    (score >= ``threshold``) in its JSON.
    """
    root = Path(root)
    config = config or SampleConfig()
    open_dataset(root, n, seed, config)
    gen = Generator(seed, config)
    todo = shard_range(n, *shard)
    counts = {"rendered": 0, "skipped": 0, "kept": 0}
    for k, i in enumerate(todo):
        d = sample_dir(root, i)
        if (d / FILES["meta"]).is_file():
            counts["skipped"] += 1
            if progress:
                progress(k + 1, len(todo), None)
            continue
        record = gen.render(i, d)
        if reference is not None:
            score = reference.score(read_ldr(d / FILES["ldr"]))
            record["filter"] = {
                "score": score,
                "threshold": threshold,
                "keep": bool(score >= threshold),
                "references": len(reference.names),
            }
            atomic_write_text(d / FILES["meta"], json.dumps(record, indent=1))
            counts["kept"] += int(score >= threshold)
        counts["rendered"] += 1
        if progress:
            progress(k + 1, len(todo), record)
    build_index(root)
    return counts


def build_index(root: str | os.PathLike) -> list[dict[str, Any]]:
    """Scan complete samples and write ``index.json`` (sorted by index); returns its entries."""
    root = Path(root)
    entries = []
    for meta in sorted((root / "samples").glob(f"*/{FILES['meta']}")):
        try:
            rec = json.loads(meta.read_text())
        except (OSError, ValueError):
            continue
        filt = rec.get("filter", {})
        entries.append(
            {
                "index": rec["index"],
                "dir": str(meta.parent.relative_to(root)),
                "sun": rec["sun"],
                "lighting": rec["lighting"].get("kind"),
                "score": filt.get("score"),
                "keep": filt.get("keep", True),
                "variant": rec["renderer"]["variant"],
            }
        )
    atomic_write_text(
        root / INDEX, json.dumps({"conventions_version": CONVENTIONS_VERSION, "samples": entries}, indent=1)
    )
    return entries


def rescore(
    root: str | os.PathLike, reference: ReferenceSet | str | os.PathLike, threshold: float = 0.7
) -> dict[str, int]:
    """Score every complete sample of the dataset at ``root`` against real photographs, in place.

    ``reference``: a :class:`ReferenceSet`, or a folder of LDR photos (read once samples are found).

    Each sample's JSON gets ``filter`` as :func:`generate` writes it (``score``: histogram
    intersection in [0, 1], ``keep``: score >= ``threshold``, ``references``), then ``index.json``
    is rebuilt. Returns ``{"samples", "kept", "references"}``; no samples: :class:`InputError`.
    """
    root = Path(root)
    metas = sorted((root / "samples").glob(f"*/{FILES['meta']}"))
    if not metas:
        raise InputError(f"{root}: no samples (not a dataset of 'solidkit synth dataset')")
    if not isinstance(reference, ReferenceSet):
        reference = ReferenceSet.from_dir(reference)
    kept = 0
    for meta in metas:
        rec = json.loads(meta.read_text())
        score = reference.score(read_ldr(meta.parent / FILES["ldr"]))
        rec["filter"] = {
            "score": score,
            "threshold": threshold,
            "keep": bool(score >= threshold),
            "references": len(reference.names),
        }
        kept += int(score >= threshold)
        atomic_write_text(meta, json.dumps(rec, indent=1))
    build_index(root)
    return {"samples": len(metas), "kept": kept, "references": len(reference.names)}


def chw_tensor(a: np.ndarray) -> Any:
    """``(H, W)`` or ``(H, W, C)`` array as a float32 ``(C, H, W)`` tensor."""
    import torch

    a = np.asarray(a, dtype=np.float32)
    if a.ndim == 2:
        a = a[..., None]
    return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1)))


class SynthDataset(torch.utils.data.Dataset):
    """A torch ``Dataset`` over a generated folder (reads ``index.json``).

    Each item is a dict of float32 tensors: ``image`` (3, H, W) LDR input in [0, 1] (the paper's
    tonemap of the HDR, as written to image.png), ``hdr`` (3, H, W), ``albedo`` (3, H, W),
    ``normal`` (3, H, W, camera frame), ``plane_distance``, ``depth``, ``shadow`` (1, H, W),
    ``global`` (3, 128, 256), ``probes`` (4, 3, 128, 256), ``probe_pixels`` (4, 2) (x, y),
    ``probe_valid`` (4,), ``sun`` (3,) in the camera panorama frame (zeros if no sun),
    ``sun_found`` (), ``K`` (3, 3), ``pitch``, ``roll`` (radians); plus ``index`` (int).

    ``keep_only=True`` drops samples the colour filter rejected; ``fields`` restricts what is read.
    """

    ALL = ("image", "hdr", "albedo", "normal", "plane_distance", "depth", "shadow", "global", "probes")

    def __init__(
        self,
        root: str | os.PathLike,
        *,
        keep_only: bool = True,
        fields: Iterable[str] | None = None,
        indices: Iterable[int] | None = None,
    ) -> None:
        self.root = Path(root)
        path = self.root / INDEX
        if not path.is_file():
            if (self.root / "samples").is_dir():
                build_index(self.root)
            else:
                raise InputError(f"{self.root}: not a synth dataset (no {INDEX})")
        data = json.loads(path.read_text())
        if data.get("conventions_version") != CONVENTIONS_VERSION:
            raise ConventionsError(f"{path}: written under conventions version {data.get('conventions_version')}")
        entries = [e for e in data["samples"] if e.get("keep", True) or not keep_only]
        if indices is not None:
            wanted = set(int(i) for i in indices)
            entries = [e for e in entries if e["index"] in wanted]
        self.entries = entries
        self.fields = tuple(fields) if fields is not None else self.ALL
        unknown = set(self.fields) - set(self.ALL)
        if unknown:
            raise InputError(f"unknown fields {sorted(unknown)}; choose from {self.ALL}")

    def __len__(self) -> int:
        return len(self.entries)

    def __getitem__(self, i: int) -> dict[str, Any]:
        import torch

        e = self.entries[i]
        d = self.root / e["dir"]
        rec = json.loads((d / FILES["meta"]).read_text())
        item: dict[str, Any] = {"index": rec["index"]}
        files = {
            "hdr": FILES["image"],
            **{k: FILES[k] for k in ("albedo", "normal", "plane_distance", "depth", "shadow", "global")},
        }
        for f in self.fields:
            if f == "image":
                item["image"] = chw_tensor(read_ldr(d / FILES["ldr"]))
            elif f == "probes":
                h = int(rec["renderer"]["probe_height"])
                item["probes"] = torch.stack(
                    [
                        chw_tensor(read_exr(d / p)[0][..., :3]) if (d / p).is_file() else torch.zeros(3, h, 2 * h)
                        for p in FILES["probes"]
                    ]
                )
            else:
                item[f] = chw_tensor(read_exr(d / files[f])[0])
        pix = np.zeros((4, 2), np.float32)
        valid = np.zeros(4, np.float32)
        for k, p in enumerate(rec["probes"][:4]):
            pix[k] = p["pixel"]
            valid[k] = 1.0
        item["probe_pixels"] = torch.from_numpy(pix)
        item["probe_valid"] = torch.from_numpy(valid)
        sun = rec["sun"]
        item["sun"] = torch.tensor(sun.get("direction_pano", [0.0, 0.0, 0.0]), dtype=torch.float32)
        item["sun_found"] = torch.tensor(float(sun["found"]))
        cam = rec["camera"]
        item["K"] = torch.tensor(cam["K"], dtype=torch.float32)
        item["pitch"] = torch.tensor(np.radians(cam["pitch_deg"]), dtype=torch.float32)
        item["roll"] = torch.tensor(np.radians(cam["roll_deg"]), dtype=torch.float32)
        return item
