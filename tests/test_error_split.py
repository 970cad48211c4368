"""lab.error_split's arithmetic on synthetic images with a known noise and bias per region, and its region masks
from world positions. No bpy, no render."""

from __future__ import annotations

import numpy as np
import pytest

from monte.lab.error_split import pixel_variance, regions_by_box, split_error

H, W, K = 64, 64, 400


def _images(sigma_left: float, bias_right: float, seed: int = 3):
    """K noisy renders of a constant 0.5 image: the left half has per-pixel noise sigma_left and no bias, the
    right half noise 0.01 and a constant offset bias_right."""
    rng = np.random.default_rng(seed)
    ref = np.full((H, W, 3), 0.5)
    sigma = np.full((H, W, 1), 0.01)
    sigma[:, : W // 2] = sigma_left
    offset = np.zeros((H, W, 1))
    offset[:, W // 2:] = bias_right
    images = [ref + offset + sigma * rng.standard_normal((H, W, 3)) for _ in range(K)]
    left = np.zeros((H, W), bool)
    left[:, : W // 2] = True
    return images, ref, {"left": left, "right": ~left}


def test_split_error_recovers_variance_and_bias_per_region():
    images, ref, regions = _images(sigma_left=0.05, bias_right=0.02)
    out = split_error(images, ref, 0.0, regions)
    # variance of a sample variance over K renders and 2048 pixels x 3 channels: relative error ~ sqrt(2/K/6144)
    assert out["left"]["variance"] == pytest.approx(0.05**2, rel=0.01)
    assert out["right"]["variance"] == pytest.approx(0.01**2, rel=0.01)
    assert out["left"]["bias2"] == pytest.approx(0.0, abs=0.05 * 0.05**2 / K * 10)
    assert out["right"]["bias2"] == pytest.approx(0.02**2, rel=0.01)
    assert out["left"]["pixels"] == out["right"]["pixels"] == H * W // 2


def test_split_error_subtracts_the_references_own_noise():
    images, ref, regions = _images(sigma_left=0.01, bias_right=0.03)
    plain = split_error(images, ref, 0.0, regions)
    own = split_error(images, ref, 1e-4, regions)
    assert own["right"]["bias2"] == pytest.approx(plain["right"]["bias2"] - 1e-4, rel=1e-9)
    assert own["right"]["variance"] == plain["right"]["variance"]


def test_split_error_rejects_one_image_and_a_reference_of_another_size():
    images, ref, regions = _images(0.01, 0.0)
    with pytest.raises(ValueError, match="at least 2 images"):
        split_error(images[:1], ref, 0.0, regions)
    with pytest.raises(ValueError, match=r"images are \(64, 64\), the reference \(32, 64\)"):
        split_error(images[:2], ref[:32], 0.0, regions)


def test_regions_by_box_gives_a_pixel_to_the_smallest_box_and_misses_to_the_background():
    pos = np.zeros((2, 3, 3))
    pos[0, 0] = (0.5, 0.5, 0.0)  # on the floor only
    pos[0, 1] = (0.1, 0.1, 0.1)  # inside the floor's box and the small cube's: the cube
    pos[0, 2] = (5.0, 5.0, 5.0)  # in no box
    pos[1, 0] = np.inf  # a miss
    pos[1, 1] = 0.0  # a miss (Position pass zero)
    pos[1, 2] = (0.9, 0.9, 0.0)
    boxes = {"floor": (np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 0.2])),
             "cube": (np.array([0.05, 0.05, 0.05]), np.array([0.15, 0.15, 0.15]))}
    r = regions_by_box(pos, boxes)
    assert r["floor"].tolist() == [[True, False, False], [False, False, True]]
    assert r["cube"].tolist() == [[False, True, False], [False, False, False]]
    assert r["background"].tolist() == [[False, False, True], [True, True, False]]


def test_pixel_variance_is_the_unbiased_variance_across_renders_averaged_over_channels():
    rng = np.random.default_rng(5)
    sigma = np.array([0.1, 0.2, 0.3])  # per channel: the mean over channels of sigma^2 is 0.14 / 3
    images = [0.5 + sigma * rng.standard_normal((32, 32, 3)) for _ in range(200)]
    v = pixel_variance(images)
    assert v.shape == (32, 32)
    # 1024 pixels x 199 degrees of freedom: the mean is within ~0.5 % of the truth (3 % allowed)
    assert v.mean() == pytest.approx((sigma**2).mean(), rel=0.03)
    two = [np.zeros((2, 2, 3)), np.ones((2, 2, 3))]  # ddof 1: (0 - 0.5)^2 + (1 - 0.5)^2 over 1
    assert np.allclose(pixel_variance(two), 0.5)
    with pytest.raises(ValueError, match="a variance needs at least 2 images"):
        pixel_variance(two[:1])
