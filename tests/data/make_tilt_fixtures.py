"""Render level city panoramas for the tilt estimator's tests (scene frame = level by construction).

Sun-and-sky lighting only: an HDR photo environment adds its own (not necessarily level) edges.
Usage: ``[H=1024] python tests/data/make_tilt_fixtures.py OUT_DIR K:BLOCK ...`` writes
OUT_DIR/level_street_K_H.jpg (level_street_{0,1,2}.jpg: H=512, renamed; level_street_3_1024.jpg:
H=1024, K:BLOCK 3:3).
"""

import os
import sys

import cv2
import numpy as np

from solidkit.envmap.io import srgb_encode
from solidkit.synth.sample import Generator, SampleConfig, derive_seed, render_panorama
from solidkit.synth.scene import to_mitsuba

gen = Generator(0, SampleConfig(width=64, height=48, candidates=2))
for k, blk in [(int(a), int(b)) for a, b in (x.split(":") for x in sys.argv[2:])]:
    block, (cam, _) = gen.block_and_view(blk, 1)
    i = 300
    while (light := gen.lighting(derive_seed(0, blk, i))).meta["kind"] != "sunsky":
        i += 1
    scene = to_mitsuba(block, light.emitter(), tex_size=16)
    pano = render_panorama(scene, cam.position, np.eye(3), int(os.environ.get("H", "512")), 16, seed=1)
    x = pano / np.percentile(pano, 97)
    img = (np.clip(np.asarray(srgb_encode(np.clip(x, 0, 1))), 0, 1) * 255 + 0.5).astype(np.uint8)
    cv2.imwrite(f"{sys.argv[1]}/level_street_{k}_{pano.shape[0]}.jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 90])
