"""Light linking and shadow linking (Blender's Object > Shading > Light Linking / Shadow Linking), as Cycles.

Light sets: an emitter (a light, or an emissive mesh) with a receiver collection lights the light set
`receiver_set` (1..63; 0: every object); each object receives the sets of its bitmask `light_sets` (bit 0 always
set in practice: unlinked emitters light everything). The add-on turns Blender's collections (Include / Exclude)
into these numbers (addon/export/light_linking.py).

Light linking, as Cycles' kernel: next-event estimation at a point selects only among the emitters linked to the
point's object (the light selection of each receiver class is its own core.lights.LightSampler over the linked
emitters), and an emitter that a BSDF ray from an unlinked object hits adds nothing; the MIS weights of the
linked ones use that class's selection, so the two strategies stay consistent. Camera rays see every emitter
(they leave no object). Objects are grouped into receiver classes (the distinct memberships of the sets some
emitter uses), one sampler each.

Shadow linking: an emitter with a blocker collection (`blocker_set` b > 0: a light, or an emissive mesh) is
shadowed only by the objects whose `shadow_sets` hold b. Its light samples are matched to it geometrically (a
light by core.light_shadow's matcher; an emissive mesh's by a ray cast against its own triangles, which must meet
the sampled point) and their shadow rays cast against those objects alone. Cycles adds, for BSDF-sampled rays, a
pass that finds such an emitter behind an object that does not block it; Monte instead takes such emitters'
contribution from light sampling alone (MIS weight 1 for their light samples, and BSDF rays after a non-delta
bounce do not see them), which has the same expectation. Rays after a delta bounce (mirrors, clear glass) still
see them, blocked by whatever they hit first. Emissive meshes whose emission a node program drives, or that move,
are not shadow-linked (core.integrator names them in a warning).

Only scenes that use linking pay for it: `LightLinks.build` and `ShadowLinks.build` return None otherwise.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .accel import Accelerator
from .light_shadow import NoShadowLights
from .lights import EmissiveTriangles, LightSample, LightSampler

__all__ = ["LightLinks", "ShadowLinks", "linked"]


def linked(membership: int, light_set: int) -> bool:
    """Whether an object of membership mask `membership` receives (or blocks) the emitter of set `light_set`."""
    return light_set == 0 or bool((int(membership) >> int(light_set)) & 1)


def _emissive_subset(tris: EmissiveTriangles, keep: np.ndarray) -> tuple[EmissiveTriangles | None, np.ndarray]:
    """The emitters `keep` (E,) bool of `tris` as their own table, and the map global emitter -> its index there
    (-1: not in it)."""
    index = np.full(tris.count, -1, np.int64)
    rows = np.flatnonzero(keep)
    index[rows] = np.arange(rows.size)
    if rows.size == 0:
        return None, index
    of_triangle = np.full(tris.emitter_of_triangle.shape, -1, np.int32)
    of_triangle[tris.triangle_id[rows]] = np.arange(rows.size, dtype=np.int32)
    return EmissiveTriangles(vertices=tris.vertices[rows], emission=tris.emission[rows],
                             triangle_id=tris.triangle_id[rows], area=tris.area[rows], normal=tris.normal[rows],
                             emitter_of_triangle=of_triangle), index


@dataclass
class LightLinks:
    """The receiver classes of a prepared scene: class_of_triangle (T,) int32; per class its LightSampler over
    the emitters linked to it and the map (E,) int64 from the scene's emitter index to the class sampler's (-1:
    the emitter does not light this class)."""

    class_of_triangle: np.ndarray
    samplers: list
    emitter_maps: list

    @property
    def emitter_linked(self) -> np.ndarray:
        """(classes, E) bool: the scene emitter lights objects of that class."""
        cached = getattr(self, "_linked", None)
        if cached is None:
            cached = self._linked = np.array([m >= 0 for m in self.emitter_maps], bool).reshape(
                len(self.emitter_maps), -1)
        return cached

    @classmethod
    def build(cls, scene, shift, emissive: EmissiveTriangles | None, radius: float, sample_world: bool,
              mesh_rows: list[tuple[int, int, int]], threads: int = 1) -> "LightLinks | None":
        """mesh_rows: per mesh with triangles, in the prepared order, (triangle count, light_sets mask, its own
        receiver_set as an emitter). None when no emitter has a receiver set. threads: as LightSampler's."""
        receiver_of_triangle = np.concatenate([np.full(t, r, np.int64) for t, _, r in mesh_rows]) \
            if mesh_rows else np.zeros(0, np.int64)
        emitter_sets = set()
        if emissive is not None:
            emitter_sets |= set(np.unique(receiver_of_triangle[emissive.triangle_id]).tolist())
        emitter_sets |= {int(getattr(lt, "receiver_set", 0)) for lt in scene.lights}
        used = sorted(s for s in emitter_sets if s > 0)
        if not used:
            return None
        keys: dict[tuple, int] = {}
        classes = []
        for t, mask, _ in mesh_rows:
            key = tuple(linked(mask, s) for s in used)
            classes.append(np.full(t, keys.setdefault(key, len(keys)), np.int32))
        if not keys:
            keys[tuple(True for _ in used)] = 0
        samplers, maps = [], []
        for key in keys:
            receives = {0} | {s for s, yes in zip(used, key) if yes}
            part = copy.copy(scene)
            part.lights = [lt for lt in scene.lights if int(getattr(lt, "receiver_set", 0)) in receives]
            tris, index = None, np.full(0 if emissive is None else emissive.count, -1, np.int64)
            if emissive is not None:
                keep = np.isin(receiver_of_triangle[emissive.triangle_id], list(receives))
                tris, index = _emissive_subset(emissive, keep)
            samplers.append(LightSampler(part, shift, tris, radius, sample_world=sample_world, threads=threads))
            maps.append(index)
        class_of_triangle = np.concatenate(classes) if classes else np.zeros(0, np.int32)
        return cls(class_of_triangle, samplers, maps)

    @staticmethod
    def _groups(classes: np.ndarray):
        for c in np.unique(classes):
            yield int(c), np.flatnonzero(classes == c)

    def sample(self, classes: np.ndarray, p, n, u_select, u, transmits) -> LightSample:
        """LightSampler.sample at points p (N, 3) whose objects are of the receiver classes `classes` (N,): each
        point selects among the emitters linked to it."""
        N = len(classes)
        out = LightSample.empty(N)
        for c, rows in self._groups(classes):
            ls = self.samplers[c].sample(p[rows], None if n is None else n[rows], u_select[rows], u[rows],
                                         transmits=None if transmits is None else transmits[rows])
            out.wi[rows], out.dist[rows], out.radiance[rows] = ls.wi, ls.dist, ls.radiance
            out.pdf[rows], out.delta[rows] = ls.pdf, ls.delta
        return out

    def triangle_weights(self, classes: np.ndarray, emitter: np.ndarray, origin, dist2, abs_cos, n, transmits):
        """For BSDF rays from objects of `classes` (N,) that hit the scene emitters `emitter` (N,): (linked (N,)
        bool, the light pdf (N,) of that hit under the class's selection, 0 where not linked)."""
        N = len(classes)
        ok = np.zeros(N, bool)
        pdf = np.zeros(N, np.float32)
        for c, rows in self._groups(classes):
            local = self.emitter_maps[c][emitter[rows]]
            have = np.flatnonzero(local >= 0)
            ok[rows[have]] = True
            if len(have):
                r = rows[have]
                pdf[r] = self.samplers[c].pdf_triangle(local[have], origin[r], dist2[r], abs_cos[r],
                                                       n=None if n is None else n[r],
                                                       transmits=None if transmits is None else transmits[r])
        return ok, pdf


# A light sample lies on a shadow-linked emissive triangle when the ray towards it meets one of those triangles
# within this fraction of the sample's distance (float32 ray casting; light samples on distinct emitters are far
# further apart).
_ON_EMITTER = 1e-3


@dataclass
class ShadowLinks:
    """The shadow-linked emitters: per blocker set b (`sets`), the matcher of its lights' samples (None when only
    emissive meshes use b) and the (T,) bool mask of the triangles that block them; `hidden` the ids of the lights
    (unseen by BSDF rays after a non-delta bounce, see the module docstring). Shadow-linked emissive triangles:
    `emitter_set` (T,) int, each triangle's position in `sets` + 1 (0: not shadow-linked), and the ray-casting
    structure of those triangles with their scene indices (`emitters`); both None when no emissive mesh is
    shadow-linked."""

    sets: list
    matchers: list
    blockers: list
    hidden: frozenset
    emitter_set: np.ndarray | None = None
    emitters: tuple | None = None

    @classmethod
    def build(cls, lights: list, shift, mesh_rows: list[tuple[int, int, int]],
              emissive: EmissiveTriangles | None = None, vertices: np.ndarray | None = None,
              triangles: np.ndarray | None = None) -> "ShadowLinks | None":
        """mesh_rows: per mesh with triangles, in the prepared order, (triangle count, shadow_sets mask, its own
        blocker_set as an emitter); emissive: the scene's light-sampled emitters, vertices / triangles the
        prepared scene's (the emitters' ray-casting structure is built from them). None when no emitter has a
        blocker set."""
        blocker_of_triangle = np.concatenate([np.full(t, b, np.int64) for t, _, b in mesh_rows]) \
            if mesh_rows else np.zeros(0, np.int64)
        linked_emitters = np.zeros(0, np.int64)
        if emissive is not None and emissive.count:
            ids = np.asarray(emissive.triangle_id, np.int64)
            linked_emitters = ids[blocker_of_triangle[ids] > 0]
        used = sorted(({int(getattr(lt, "blocker_set", 0)) for lt in lights}
                       | set(np.unique(blocker_of_triangle[linked_emitters]).tolist())) - {0})
        if not used:
            return None
        sets, matchers, blockers, hidden = [], [], [], set()
        for b in used:
            chosen = [lt for lt in lights if int(getattr(lt, "blocker_set", 0)) == b]
            hidden |= {id(lt) for lt in chosen}
            sets.append(b)
            matchers.append(NoShadowLights.of(chosen, shift))
            blockers.append(np.concatenate([np.full(t, linked(mask, b), bool) for t, mask, _ in mesh_rows])
                            if mesh_rows else np.zeros(0, bool))
        emitter_set = emitters = None
        if len(linked_emitters):
            emitter_set = np.zeros(len(blocker_of_triangle), np.int64)
            position = {b: j + 1 for j, b in enumerate(sets)}
            emitter_set[linked_emitters] = [position[int(b)] for b in blocker_of_triangle[linked_emitters]]
            keep = np.sort(linked_emitters)
            emitters = (Accelerator(vertices, np.ascontiguousarray(triangles[keep], np.int32)), keep)
        return cls(sets, matchers, blockers, frozenset(hidden), emitter_set, emitters)

    def set_of_samples(self, p, wi, dist) -> np.ndarray:
        """(N,) int: for each light sample (from p towards wi, at dist), the position in `sets` + 1 of the
        shadow-linked emitter it lies on, 0 for every other emitter."""
        out = np.zeros(len(dist), np.int64)
        for j, matcher in enumerate(self.matchers):
            if matcher is not None:
                out[(out == 0) & matcher.matches(p, wi, dist)] = j + 1
        if self.emitters is not None:
            rows = np.flatnonzero((out == 0) & np.isfinite(dist) & (dist > 0))
            if len(rows):
                accel, keep = self.emitters
                reach = np.asarray(dist[rows], np.float32)
                hits = accel.intersect(np.asarray(p[rows], np.float32), np.asarray(wi[rows], np.float32),
                                       (reach * np.float32(1 + _ON_EMITTER)).astype(np.float32))
                on = (hits.prim >= 0) & (np.abs(hits.t - reach) <= np.float32(_ON_EMITTER) * reach)
                out[rows[on]] = self.emitter_set[keep[hits.prim[on]]]
        return out

    def hides_triangles(self, prim: np.ndarray) -> np.ndarray:
        """(N,) bool: the triangles `prim` are shadow-linked emitters (BSDF rays after a non-delta bounce do not
        count them)."""
        if self.emitter_set is None:
            return np.zeros(len(prim), bool)
        return self.emitter_set[prim] > 0
