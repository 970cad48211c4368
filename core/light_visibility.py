"""A light's per-ray visibility (Blender's Object > Visibility > Ray Visibility > Diffuse, Glossy, Transmission on a
light object; core.scene lights' visible_diffuse / visible_glossy / visible_transmission), as Cycles applies it:

- BSDF rays of a kind the light hides from (core.ray_visibility's kinds: the lobe that sent them) pass through
  it (it is unlit for them in core.lights.LightSampler.intersect; the MIS weights of the others unchanged);
- next-event estimation still selects it, but evaluates only the lobes of the kinds it is visible to (Cycles
  excludes the closures: diffuse lobes for Diffuse, glossy lobes for Glossy, refraction lobes for
  Transmission, and glass lobes, both glossy and transmitting, only with Glossy and Transmission both off). The BSDF pdf used for MIS stays the whole BSDF's, the pdf with which BSDF sampling reaches the
  light through the lobes that still see it, so the two strategies' weights sum to one.

The sampler does not say which light a sample came from: samples are matched to the lights geometrically
(core.light_shadow's matcher). Camera visibility is `visible_camera` (core.lights). Only scenes with such a light
pay for this (`LightVisibility.build` returns None otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bsdf_kernels import DIFFUSE, GLASS, GLOSSY, REFRACTION
from .light_shadow import NoShadowLights
from .ray_visibility import DIFFUSE_RAY, GLOSSY_RAY, TRANSMISSION_RAY

# flag -> (the ray kind it hides the light from, the lobe kinds next-event estimation leaves out)
FLAGS = {"visible_diffuse": (DIFFUSE_RAY, (DIFFUSE,)), "visible_glossy": (GLOSSY_RAY, (GLOSSY,)),
         "visible_transmission": (TRANSMISSION_RAY, (REFRACTION,))}
# glass lobes reflect and transmit: left out only when both of these are off (as Cycles' closure exclusion)
_GLASS_FLAGS = ("visible_glossy", "visible_transmission")


@dataclass
class LightVisibility:
    """hidden_from: ray kind -> ids of the lights those rays do not see; groups: per distinct set of flags off,
    (the lobe kinds left out, the matcher of those lights' samples)."""

    hidden_from: dict
    groups: list

    @classmethod
    def build(cls, lights: list, shift) -> "LightVisibility | None":
        by_flags: dict[tuple, list] = {}
        hidden_from: dict[int, set] = {}
        for lt in lights:
            off = tuple(flag for flag in FLAGS if not getattr(lt, flag, True))
            if off:
                by_flags.setdefault(off, []).append(lt)
                for flag in off:
                    hidden_from.setdefault(FLAGS[flag][0], set()).add(id(lt))
        if not by_flags:
            return None
        groups = [(tuple(k for flag in off for k in FLAGS[flag][1])
                   + ((GLASS,) if all(flag in off for flag in _GLASS_FLAGS) else ()), NoShadowLights.of(chosen, shift))
                  for off, chosen in by_flags.items()]
        return cls({kind: frozenset(ids) for kind, ids in hidden_from.items()}, groups)

    def hidden(self, kind: int) -> frozenset:
        """Ids of the lights rays of this kind (core.ray_visibility) do not see."""
        return self.hidden_from.get(int(kind), frozenset())

    def group_of_samples(self, p, wi, dist) -> np.ndarray:
        """(N,) int: for each light sample, the position in `groups` + 1 of the light it lies on, 0 for lights
        visible to every kind."""
        out = np.zeros(len(dist), np.int64)
        for j, (_, matcher) in enumerate(self.groups):
            out[(out == 0) & matcher.matches(p, wi, dist)] = j + 1
        return out
