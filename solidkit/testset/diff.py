"""``solidkit testset diff OLD NEW``: what changed between two versions of a test set.

Two test sets are compared by their manifests only (``testset.json``; the checksums say which files
changed): scenes and probes added or removed; per scene the sun (found, angle between the two
directions, source); per probe the pixel (distance in full-resolution pixels), the rotation
(angle of ``R_new R_oldᵀ``), the provenance of both; and the files whose content changed. This
is what a changelog between two dataset versions needs; both sides must be readable test sets.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from solidkit.envmap.coords import angular_distance
from solidkit.testset.build import load_testset

__all__ = ["TestsetDiff", "diff_testsets"]


@dataclass
class TestsetDiff:
    """Differences between two test sets (``old`` -> ``new``)."""

    old_version: str
    new_version: str
    scenes_added: list[str] = field(default_factory=list)
    scenes_removed: list[str] = field(default_factory=list)
    probes_added: list[str] = field(default_factory=list)
    probes_removed: list[str] = field(default_factory=list)
    changes: list[dict[str, Any]] = field(default_factory=list)
    files_changed: list[str] = field(default_factory=list)
    files_added: list[str] = field(default_factory=list)
    files_removed: list[str] = field(default_factory=list)

    __test__ = False

    @property
    def same(self) -> bool:
        return self.old_version == self.new_version

    def to_json(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__} | {"same": self.same}

    def lines(self) -> list[str]:
        """A human-readable changelog, one line per change."""
        if self.same:
            return [f"identical content ({self.new_version})"]
        out = [f"{self.old_version} -> {self.new_version}"]
        out += [f"+ scene {s}" for s in self.scenes_added] + [f"- scene {s}" for s in self.scenes_removed]
        out += [f"+ probe {p}" for p in self.probes_added] + [f"- probe {p}" for p in self.probes_removed]
        out += [f"~ {c['what']} {c['where']}: {c['detail']}" for c in self.changes]
        out.append(
            f"files: {len(self.files_changed)} changed, {len(self.files_added)} added, {len(self.files_removed)} "
            "removed"
        )
        return out


def _sun_dir(sun) -> np.ndarray | None:
    return np.asarray(sun.direction, np.float64) if sun.found and sun.direction else None


def _rot_angle(a, b) -> float:
    R = np.asarray(b, np.float64) @ np.asarray(a, np.float64).T
    return math.degrees(math.acos(float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def diff_testsets(
    old: str | os.PathLike, new: str | os.PathLike, *, tol_deg: float = 1e-6, tol_px: float = 1e-6
) -> TestsetDiff:
    """Compare the test sets at ``old`` and ``new`` (see the module docstring)."""
    a, b = load_testset(Path(old)), load_testset(Path(new))
    d = TestsetDiff(a.dataset_version, b.dataset_version)
    sa, sb = {s.id: s for s in a.scenes}, {s.id: s for s in b.scenes}
    d.scenes_added = sorted(set(sb) - set(sa))
    d.scenes_removed = sorted(set(sa) - set(sb))
    for sid in sorted(set(sa) & set(sb)):
        s0, s1 = sa[sid], sb[sid]
        u0, u1 = _sun_dir(s0.sun), _sun_dir(s1.sun)
        if (u0 is None) != (u1 is None):
            d.changes.append(
                {"what": "sun", "where": sid, "detail": f"found {s0.sun.found} -> {s1.sun.found} ({s1.sun.source})"}
            )
        elif u0 is not None:
            ang = math.degrees(float(angular_distance(u0, u1)))
            if ang > tol_deg or s0.sun.source != s1.sun.source:
                d.changes.append(
                    {
                        "what": "sun",
                        "where": sid,
                        "angle_deg": ang,
                        "detail": f"moved {ang:.3f} deg ({s0.sun.source} -> {s1.sun.source})",
                    }
                )
        p0, p1 = {p.id: p for p in s0.probes}, {p.id: p for p in s1.probes}
        d.probes_added += [f"{sid}/{p}" for p in sorted(set(p1) - set(p0))]
        d.probes_removed += [f"{sid}/{p}" for p in sorted(set(p0) - set(p1))]
        for pid in sorted(set(p0) & set(p1)):
            q0, q1 = p0[pid], p1[pid]
            dist = float(np.hypot(q1.pixel_full[0] - q0.pixel_full[0], q1.pixel_full[1] - q0.pixel_full[1]))
            if dist > tol_px or q0.pixel_source != q1.pixel_source:
                d.changes.append(
                    {
                        "what": "pixel",
                        "where": f"{sid}/{pid}",
                        "distance_px": dist,
                        "detail": f"moved {dist:.2f} px ({q0.pixel_source} -> {q1.pixel_source})",
                    }
                )
            ang = _rot_angle(q0.rotation, q1.rotation)
            if ang > tol_deg or q0.alignment.source != q1.alignment.source:
                d.changes.append(
                    {
                        "what": "rotation",
                        "where": f"{sid}/{pid}",
                        "angle_deg": ang,
                        "detail": f"turned {ang:.3f} deg ({q0.alignment.source} -> {q1.alignment.source})",
                    }
                )
            if sorted(q0.flags) != sorted(q1.flags):
                d.changes.append({"what": "flags", "where": f"{sid}/{pid}", "detail": f"{q0.flags} -> {q1.flags}"})
    fa, fb = a.files, b.files
    d.files_added = sorted(set(fb) - set(fa))
    d.files_removed = sorted(set(fa) - set(fb))
    d.files_changed = sorted(k for k in set(fa) & set(fb) if fa[k].sha256 != fb[k].sha256)
    return d
