"""Cycles' light groups (View Layer > Light Groups): a pass "Combined_<name>" per group with the light its emitters give.

An emitter (a light, an emissive mesh, the world) names its group (`lightgroup` on core.scene lights, Mesh and
World; a Sky Texture's sun disc, one of `World.lights`, goes with the world). Scene.light_groups lists the view
layer's groups; an emitter whose group is not listed, or that names none, is in no group, as in Cycles. A group's
pass holds, per pixel, what that group's emitters add to Combined, with the same path throughput and MIS weights:

- light found by next-event estimation, attributed to the sampled emitter (Cycles' shadow path light group);
- emission a ray finds: an emissive triangle's, a light's surface, the world (camera rays too: a light seen by the
  camera, the world's background), each to its emitter's group.

So when every emitter is in some group the groups sum to Combined (up to float32 rounding), Film > Transparent
and holdouts included (what the image lost the groups lost too).

How the contributions are attributed without the light sampler reporting which emitter it picked: a light
sample is matched to the analytic lights geometrically (core.light_shadow's matcher, per group); one at
infinity on no sun is the world's; any other lies on an emissive triangle, found by a ray from the shadow ray's
origin against the grouped emitters' triangles alone, to just past the sampled distance. Emission along a ray
(lights' surfaces and the world, summed by core.lights.LightSampler.intersect) is split in the ratio of each
group's own emission along it (the other lights hidden, as light linking hides them: selection and MIS
unchanged). Two emitters would have to overlap for a sample to be matched to the wrong one.

Only scenes with light groups pay for this (LightGroups.build returns None otherwise); the groups draw no random
numbers, so Combined is bit for bit the image rendered without them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .light_shadow import NoShadowLights

SHADOW_CATCHER_WARNING = ("light groups with a shadow catcher: the groups hold the light of the paths as traced, "
                          "without the catcher's own compositing, so they do not sum to Combined")
PASS_PREFIX = "Combined_"  # Cycles' (and Blender's) pass name of a light group: "Combined_" + the group's name


def pass_name(group: str) -> str:
    """The render pass of light group `group`, as Cycles names it."""
    return PASS_PREFIX + group


@dataclass
class LightGroups:
    """A prepared scene's light groups: `names`; per triangle its emitter's group (T,) int32 (-1: none);
    per group the ids of the scene lights outside it (`hidden`, what its share of core.lights.LightSampler's
    `intersect` does not see), whether the world is in it, and the geometric matcher of its analytic lights
    (None: it has none); `ungrouped`: the matcher of the analytic lights in no group (None: none); `emitters`: the
    (ray-casting structure, scene triangle index) of the grouped emissive triangles, or None; `lights_grouped`:
    every analytic light and the world are in some group (the groups' emission along a ray then sums to all)."""

    names: tuple[str, ...]
    group_of_triangle: np.ndarray
    hidden: list
    world_in: list
    matchers: list
    ungrouped: NoShadowLights | None
    world_group: int
    emitters: tuple | None
    lights_grouped: bool

    @property
    def count(self) -> int:
        return len(self.names)

    @classmethod
    def build(cls, scene, shift, triangle_groups: np.ndarray, emitting: np.ndarray, vertices, triangles
              ) -> "LightGroups | None":
        """triangle_groups: (T,) the group name index of each prepared triangle's mesh (-1: none); emitting: (T,)
        bool, the triangles light sampling may pick (emissive, or textured emitters). None without light groups."""
        names = tuple(scene.light_groups)
        if not names:
            return None
        if scene.has_shadow_catcher and SHADOW_CATCHER_WARNING not in scene.warnings:
            scene.warnings.append(SHADOW_CATCHER_WARNING)
        index = {name: i for i, name in enumerate(names)}
        world_group = index.get(getattr(scene.world, "lightgroup", ""), -1)
        world_lights = {id(lt) for lt in getattr(scene.world, "lights", [])}

        def group_of(light) -> int:
            if id(light) in world_lights:  # a sky's sun disc is the world's light
                return world_group
            return index.get(getattr(light, "lightgroup", ""), -1)

        groups = [group_of(lt) for lt in scene.lights]
        hidden, world_in, matchers = [], [], []
        for g in range(len(names)):
            hidden.append(frozenset(id(lt) for lt, lg in zip(scene.lights, groups) if lg != g))
            world_in.append(world_group == g)
            matchers.append(NoShadowLights.of([lt for lt, lg in zip(scene.lights, groups) if lg == g], shift))
        group_of_triangle = np.asarray(triangle_groups, np.int32)
        keep = np.flatnonzero((group_of_triangle >= 0) & np.asarray(emitting, bool))
        emitters = None
        if len(keep):
            from .accel import Accelerator

            emitters = (Accelerator(vertices, triangles[keep]), keep.astype(np.int32))
        ungrouped = [lt for lt, lg in zip(scene.lights, groups) if lg < 0]
        return cls(names, group_of_triangle, hidden, world_in, matchers, NoShadowLights.of(ungrouped, shift),
                   world_group, emitters, not ungrouped and world_group >= 0)

    def of_light_samples(self, p: np.ndarray, wi: np.ndarray, dist: np.ndarray, origin: np.ndarray,
                         direction: np.ndarray, triangles_only: bool = False) -> np.ndarray:
        """(N,) int32 group of each light sample (from shading points p towards unit wi, at dist, inf at infinity;
        origin, direction: its shadow ray's, which aims at the sampled point from an origin lifted off the
        surface), -1 where its emitter is in no group. triangles_only: the samples are of emissive triangles
        (core.textured_emitters)."""
        n = len(dist)
        out = np.full(n, -1, np.int32)
        if n == 0:
            return out
        dist = np.asarray(dist, np.float64)
        on_light = np.zeros(n, bool)
        if not triangles_only:  # each group's lights, then the ungrouped ones, over the samples left
            left = np.arange(n)
            for g, matcher in enumerate(self.matchers + [self.ungrouped]):
                if matcher is not None and len(left):
                    found = matcher.matches(p[left], wi[left], dist[left])
                    on_light[left[found]] = True
                    if g < len(self.matchers):
                        out[left[found]] = g
                    left = left[~found]
        far = ~np.isfinite(dist)
        if not triangles_only and self.world_group >= 0:
            out[far & ~on_light] = self.world_group
        rest = np.flatnonzero(~far & ~on_light)
        if len(rest) and self.emitters is not None:
            accel, scene_index = self.emitters
            o = np.ascontiguousarray(origin[rest], np.float32)
            target = np.asarray(p, np.float64)[rest] + np.asarray(wi, np.float64)[rest] * dist[rest, None]
            reach = np.linalg.norm(target - o, axis=1)
            hits = accel.intersect(o, np.ascontiguousarray(direction[rest], np.float32),
                                   (reach * (1 + 1e-3) + 1e-4).astype(np.float32))
            found = hits.prim >= 0
            out[rest[found]] = self.group_of_triangle[scene_index[hits.prim[found]]]
            lost = np.flatnonzero(~found)
            if len(lost):  # (a point on an edge, a grazing ray) a short ray across the sampled point itself
                w = np.asarray(direction, np.float64)[rest[lost]]
                step = 1e-4 * (reach[lost] + np.abs(target[lost]).max(axis=1) + 1e-3)
                back = accel.intersect(np.ascontiguousarray(target[lost] + w * step[:, None], np.float32),
                                       np.ascontiguousarray(-w, np.float32), (2 * step).astype(np.float32))
                ok = back.prim >= 0
                out[rest[lost[ok]]] = self.group_of_triangle[scene_index[back.prim[ok]]]
        return out


class LightGroupSamples:
    """The light groups of N camera samples while their paths are traced: `values` (N, G, 3) float32 sums."""

    def __init__(self, n: int, groups: int) -> None:
        self._groups = np.zeros((groups, n, 3), np.float32)  # group-major: each group's block is contiguous

    @property
    def values(self) -> np.ndarray:
        """(N, G, 3) view of the sums (writable)."""
        return self._groups.transpose(1, 0, 2)

    def add(self, idx: np.ndarray, value: np.ndarray, groups) -> None:
        """Add the contributions `value` (M, 3) of samples idx (each at most once) to their groups: `groups` an
        (M,) int array (-1: no group), or (rows, (G, K, 3) shares of each group in those K rows; the others add
        nothing)."""
        value = np.asarray(value, np.float32)
        if isinstance(groups, tuple):
            rows, shares = groups
            idx, value = idx[rows], value[rows]
            for g, share in enumerate(shares):
                self._groups[g][idx] += value * share
            return
        if isinstance(groups, np.ndarray) and groups.ndim == 1:
            for g in np.unique(groups[groups >= 0]):
                rows = np.flatnonzero(groups == g)
                self._groups[int(g)][idx[rows]] += value[rows]
            return
        raise TypeError(f"light groups: expected group indices or (rows, shares), got {type(groups).__name__}")


def emission_shares(per_group: list, total: np.ndarray) -> np.ndarray:
    """(G, M, 3) float32 shares of each group in emission along rays: per_group[g] (M, 3) the group's own emission,
    `total` (M, 3) everything's; 0 where total is 0."""
    total = np.asarray(total, np.float64)
    safe = np.where(total > 0, total, 1.0)
    return np.stack([np.where(total > 0, np.clip(np.asarray(e, np.float64) / safe, 0, 1), 0.0)
                     for e in per_group]).astype(np.float32)


def images(means: np.ndarray, names) -> dict[str, np.ndarray]:
    """The light group passes from the per-pixel means (..., G, 3): pass name (Combined_<group>) -> (..., 3)."""
    return {pass_name(name): np.asarray(means[..., g, :], np.float32) for g, name in enumerate(names)}
