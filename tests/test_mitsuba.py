"""Mitsuba 3 renders the bench's Cornell box as Monte does (lab/mitsuba_scene.py), so that `monte bench --vs
mitsuba` compares like with like; and the translation refuses what it does not carry over.

Mitsuba is an optional development dependency (requirements/rivals.txt, ~70 MB of wheels, not in CI): the
rendering tests skip where it is not installed. They use the scalar_rgb variant, which needs no system LLVM.
"""

from __future__ import annotations

import numpy as np
import pytest

from monte.core.builtin_scenes import cornell_box
from monte.core.render import render
from monte.core.scene import Lobe, Material
from monte.core.settings import RenderSettings
from monte.lab.mitsuba_scene import MitsubaSceneError, mitsuba_scene_dict

# 590 k samples each: over seeds, Mitsuba's channel means spread by ~0.2 %, Monte's by ~0.1 %, so the test tells
# a mismatch of 1.5 % or more (the one-sided lamp of the control: -8.7 %) from noise; the two agree within 0.5 %.
RES, SPP = 48, 256
TOLERANCE = 0.01  # relative, per channel mean


def _mitsuba():
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (optional development dependency: "
                                               "pip install -r requirements/rivals.txt)")
    import drjit as dr

    mi.set_variant("scalar_rgb")
    dr.set_thread_count(2)
    return mi


def _mitsuba_image(mi, scene, tmp_path, spp: int, two_sided_emitters: bool = True) -> np.ndarray:
    desc = mitsuba_scene_dict(scene, tmp_path, spp=spp, max_bounces=16, two_sided_emitters=two_sided_emitters)
    return np.array(mi.render(mi.load_dict(desc), spp=spp, seed=7), dtype=np.float64)[..., :3]


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(a / b - 1.0)


def test_mitsuba_cornell_box_has_montes_means(tmp_path):
    """Whole-image channel means within 1 %, and the left and right thirds (the red and blue walls: a mirrored
    camera would swap them) within 3 %. Control: Mitsuba's own one-sided lamp, the mismatch the flipped
    duplicate removes, is outside the 1 % in every channel."""
    mi = _mitsuba()
    scene = cornell_box((RES, RES))
    monte = render(scene, RenderSettings(spp=SPP, seed=3, threads=2, filter_type="box", filter_width=1.0,
                                         aovs=False).validate()).color[..., :3].astype(np.float64)
    mitsuba = _mitsuba_image(mi, scene, tmp_path, SPP)
    m_mean, s_mean = monte.reshape(-1, 3).mean(0), mitsuba.reshape(-1, 3).mean(0)
    assert np.all(_relative(s_mean, m_mean) < TOLERANCE), (s_mean, m_mean)
    third = RES // 3
    for cols in (slice(0, third), slice(RES - third, RES)):
        a, b = monte[:, cols].reshape(-1, 3).mean(0), mitsuba[:, cols].reshape(-1, 3).mean(0)
        assert np.all(_relative(b, a) < 0.03), (cols, a, b)
    assert monte[:, :third, 0].mean() > 1.5 * monte[:, -third:, 0].mean()  # red wall on the left

    (tmp_path / "one_sided").mkdir()
    one_sided = _mitsuba_image(mi, scene, tmp_path / "one_sided", SPP // 4, two_sided_emitters=False)
    o_mean = one_sided.reshape(-1, 3).mean(0)
    assert np.all(_relative(o_mean, m_mean) > TOLERANCE), (o_mean, m_mean)


def test_mitsuba_translation_refuses_what_it_does_not_carry(tmp_path):
    scene = cornell_box((8, 8))
    scene.materials[4] = Material("rough_mirror", [Lobe("glossy", np.full(3, 0.9), roughness=0.3)])
    with pytest.raises(MitsubaSceneError, match=r"material 'rough_mirror': a 'glossy' lobe \(roughness 0.3, "
                                                r"fresnel 'none'\) is not translated to Mitsuba"):
        mitsuba_scene_dict(scene, tmp_path, spp=1, max_bounces=4)
    scene = cornell_box((8, 8))
    with pytest.raises(MitsubaSceneError, match=r"pixel filter 'blackman-harris': Mitsuba gets box"):
        mitsuba_scene_dict(scene, tmp_path, spp=1, max_bounces=4, filter_type="blackman-harris")


def test_bench_vs_mitsuba_argument_errors(tmp_path):
    """`monte bench --vs mitsuba` names what is missing or not comparable before rendering anything."""
    pytest.importorskip("bpy", reason="the bench needs the bpy module")
    from monte.cli import build_parser
    from monte.lab.bench_mitsuba import run_from_args

    def args(*extra):
        return build_parser().parse_args(["bench", "--vs", "mitsuba", *extra])

    with pytest.raises(ValueError, match=r"--vs mitsuba needs --reference-dir DIR"):
        run_from_args(args("-o", str(tmp_path)), {})
    with pytest.raises(ValueError, match=r"--vs mitsuba benches the Cornell box only"):
        run_from_args(args("--scene", "glass", "--reference-dir", str(tmp_path), "-o", str(tmp_path)), {})
    with pytest.raises(ValueError, match=r"--vs mitsuba fixes these settings for a fair comparison: spp"):
        run_from_args(args("--reference-dir", str(tmp_path), "-o", str(tmp_path)), {"spp": 8})
