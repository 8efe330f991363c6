"""Hand-built RGB-D scenes with exact ground truth for the cue tests."""

from __future__ import annotations

import numpy as np
import pytest

WALL = (110, 120, 140)  # bluish grey
CLOTH = (30, 30, 40)  # dark clothing: grayscale difference from the wall ~88
SKIN = (200, 150, 120)  # skin: grayscale difference from the wall ~47


def build_scene(
    h: int = 200,
    w: int = 240,
    hand: tuple[float, float] = (150.0, 90.0),
    radius: float = 14.0,
    *,
    torso: bool = True,
    noise: float = 2.0,
    seed: int = 0,
    shift: tuple[int, int] = (0, 0),
):
    """Colour, depth, their backgrounds and the hand mask of a tiny scene.

    The hand is a disc at ``hand`` (u, v) in front of a dark torso rectangle;
    the wall is textured. ``shift`` moves every scene element (not the wall
    texture, which is part of the background) by (du, dv) pixels.
    """
    rng = np.random.default_rng(seed)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    texture = 6.0 * np.sin(uu / 7.0) * np.cos(vv / 9.0)
    bg = np.clip(np.array(WALL, float)[None, None, :] + texture[..., None], 0, 255)
    bg_depth = np.full((h, w), 3000.0)
    color = bg.copy()
    depth = bg_depth.copy()
    du, dv = shift
    if torso:
        body = (uu >= 40 + du) & (uu < 120 + du) & (vv >= 40 + dv) & (vv < 190 + dv)
        color[body] = CLOTH
        depth[body] = 1500.0
        arm = (uu >= 110 + du) & (uu < hand[0] + du) & (np.abs(vv - hand[1] - dv) < 5)
        color[arm] = CLOTH
        depth[arm] = 1350.0
    disc = (uu - hand[0] - du) ** 2 + (vv - hand[1] - dv) ** 2 <= radius**2
    color[disc] = SKIN
    depth[disc] = 1200.0
    color_noisy = np.clip(color + rng.normal(0, noise, color.shape), 0, 255).round().astype(np.uint8)
    bg_noisy = np.clip(bg + rng.normal(0, noise, bg.shape), 0, 255).round().astype(np.uint8)
    return {
        "color": color_noisy,
        "background": bg_noisy,
        "depth": depth.round().astype(np.uint16),
        "bg_depth": bg_depth.astype(np.uint16),
        "hand": disc,
        "truth": (hand[0] + du, hand[1] + dv),
    }


@pytest.fixture
def scene():
    """The :func:`build_scene` builder."""
    return build_scene
