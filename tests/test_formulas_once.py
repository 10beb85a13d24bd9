"""Each formula once, in the lowest layer that needs it (README "Layout"): a scan of the package's sources.

Every rule names a formula, its one home, and a pattern that recognises a second copy written by
hand. ``test_rules_recognise_copies`` feeds each pattern the copies this scan was written against
(so a rule that matches nothing cannot pass unnoticed).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "solidkit"

# name: (home relative to solidkit/, pattern, copies that must match)
RULES = {
    "Rec. 709 luminance weights": (
        "envmap/sun.py",
        r"0\.2126|0\.7152|0\.0722",
        ["lum = img @ np.array([0.2126, 0.7152, 0.0722])", "0.2126 * r + 0.7152 * g + 0.0722 * b"],
    ),
    "focal length from a field of view (f = (W/2) / tan(fov/2))": (
        "envmap/perspective.py",
        r"/\s*\(?\s*(?:math|np|numpy|torch)\.tan\(",
        ["f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)", "f = (width / 2.0) / np.tan(fov / 2)"],
    ),
    "ideal K or K from a FOV defined again": (
        "envmap/perspective.py",
        r"def\s+(?:default_intrinsics|intrinsics|intrinsics_from_fov|ideal_intrinsics|scale_intrinsics)\s*\(",
        [
            "def intrinsics(width, height, hfov_deg):",
            "def default_intrinsics(height, width, hfov_deg):",
            "def intrinsics_from_fov(width, height, hfov):",
        ],
    ),
    "pixel coordinates and K rescaled about pixel centres (c' = (c + 0.5) s - 0.5)": (
        "envmap/perspective.py",
        r"\+\s*0\.5\)\s*\*\s*\w+\s*-\s*0\.5|0\.5\s*\*\s*\w+\s*-\s*0\.5\]",
        [
            "K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5",
            "S = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1]])",
            '"center": ((cx + 0.5) * s - 0.5, (cy + 0.5) * s - 0.5)',
        ],
    ),
    "pixel rays (x - cx) / fx": (
        "envmap/perspective.py",
        r"-\s*\w+\[0,\s*2\]\)\s*/\s*\w+\[0,\s*0\]",
        ["np.stack([(x - K[0, 2]) / K[0, 0], (y - K[1, 2]) / K[1, 1], np.ones_like(x)], axis=-1)"],
    ),
    "angle wrap ((a + pi) mod 2 pi - pi, (a + 180) mod 360 - 180)": (
        "envmap/coords.py",
        r"\+\s*(?:180(?:\.0)?|half|(?:math|np|torch)\.pi)\)\s*%\s*\(?\s*(?:360(?:\.0)?|period|2(?:\.0)?\s*\*\s*(?:math|np|torch)\.pi)",
        [
            "phi = (phi + math.pi) % (2 * math.pi) - math.pi",
            "return (v + 180.0) % 360.0 - 180.0",
            "daz = abs((float(phi_p) - float(phi_t) + math.pi) % (2 * math.pi) - math.pi)",
            "own = np.abs((az - yaw + math.pi) % (2.0 * math.pi) - math.pi) <= step / 2.0",
            "x = np.array([lat, (lon_sub + hour_angle + 180.0) % 360.0 - 180.0])",
        ],
    ),
    "sun errors from the angles of two directions (azimuth gap, elevation gap)": (
        "metrics/sun.py",
        r"=\s*angles_from_direction\([^)]*\),\s*angles_from_direction\(",
        [
            "(pa, pe), (ta, te) = angles_from_direction(d[v]), angles_from_direction(t[v])",
            "(phi_p, th_p), (phi_t, th_t) = angles_from_direction(p), angles_from_direction(t)",
        ],
    ),
    "pixel rays by inverting K": (
        "envmap/perspective.py",
        r"linalg\.inv\(\s*K\b|\binv\(\s*K\s*\)",
        ["rays = pix @ torch.linalg.inv(K).transpose(-1, -2)", "Kinv = np.linalg.inv(K)"],
    ),
    "rotation vector -> matrix (Rodrigues)": (
        "envmap/coords.py",
        r"\(1\s*-\s*(?:math|np)\.cos\(\w+\)\)\s*\*\s*\(?\s*K\s*@\s*K",
        [
            "np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * (K @ K)",
            "np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K",
        ],
    ),
}


def sources() -> list[tuple[str, str]]:
    return [(str(p.relative_to(PACKAGE)), p.read_text(encoding="utf-8")) for p in sorted(PACKAGE.rglob("*.py"))]


@pytest.mark.parametrize("name", sorted(RULES))
def test_formula_has_one_home(name: str):
    home, pattern, _ = RULES[name]
    rx = re.compile(pattern)
    copies = [
        f"solidkit/{rel}:{i}: {line.strip()}"
        for rel, text in sources()
        if rel != home
        for i, line in enumerate(text.splitlines(), 1)
        if rx.search(line)
    ]
    assert not copies, f"{name}: written again outside solidkit/{home}:\n" + "\n".join(copies)


@pytest.mark.parametrize("name", sorted(RULES))
def test_rules_recognise_copies(name: str):
    home, pattern, examples = RULES[name]
    assert (PACKAGE / home).is_file()
    for ex in examples:
        assert re.search(pattern, ex), f"{name}: the rule misses {ex!r}"
