"""Blender's Light Linking and Shadow Linking (Object > Shading, Blender 4.0+) -> core light sets.

An emitter (a light, or an emissive mesh for light linking) with a receiver (blocker) collection gets a light
set, one per distinct collection, as Cycles numbers them (1..63; 0: no linking). An object belongs to the set of
a collection as Blender's manual states: when the collection includes some objects, those included and not
excluded; when it only excludes, every object not excluded. A child collection's Include / Exclude applies to
every object inside it. Objects are matched by their original (instances share their object's sets).
Core fields: core.scene lights' and Mesh.receiver_set / blocker_set, Mesh.light_sets / shadow_sets
(core.light_linking renders them).
"""

from __future__ import annotations

from ...core.scene import MAX_LIGHT_SETS

_ALL = -1  # every set


def _collection_members(collection) -> tuple[set[int], set[int]]:
    """(included, excluded) original-object pointers of a linking collection."""
    included: set[int] = set()
    excluded: set[int] = set()
    for entry, obj in zip(collection.collection_objects, collection.objects):
        state = getattr(getattr(entry, "light_linking", None), "link_state", "INCLUDE")
        (excluded if state == "EXCLUDE" else included).add(obj.original.as_pointer())
    for entry, child in zip(collection.collection_children, collection.children):
        state = getattr(getattr(entry, "light_linking", None), "link_state", "INCLUDE")
        (excluded if state == "EXCLUDE" else included).update(o.original.as_pointer() for o in child.all_objects)
    return included, excluded


class LightLinking:
    """The light sets of one export. `active` is False when no emitter links (nothing then changes)."""

    def __init__(self, objects, warnings: list[str]) -> None:
        # collection pointer -> (set index, included, excluded), for receivers and for blockers
        self._sets: dict[str, dict[int, tuple[int, set, set]]] = {"receiver_collection": {},
                                                                    "blocker_collection": {}}
        self._warnings = warnings
        for obj in objects:
            linking = getattr(obj, "light_linking", None)
            if linking is None:
                continue
            for attr, found in self._sets.items():
                coll = getattr(linking, attr, None)
                if coll is None or coll.original.as_pointer() in found:
                    continue
                if len(found) >= MAX_LIGHT_SETS - 1:
                    label = "Light Linking" if attr == "receiver_collection" else "Shadow Linking"
                    warnings.append(f"{label}: more than {MAX_LIGHT_SETS - 1} collections; collection "
                                    f"{coll.name!r} is ignored (its emitters light / are blocked by every object)")
                    found[coll.original.as_pointer()] = (0, set(), set())
                    continue
                found[coll.original.as_pointer()] = (len(found) + 1, *_collection_members(coll))

    @property
    def active(self) -> bool:
        return any(s for found in self._sets.values() for s, _, _ in found.values())

    def _set_of(self, obj, attr: str) -> int:
        coll = getattr(getattr(obj, "light_linking", None), attr, None)
        if coll is None:
            return 0
        return self._sets[attr].get(coll.original.as_pointer(), (0,))[0]

    def emitter(self, obj) -> tuple[int, int]:
        """(receiver_set, blocker_set) of a light or emissive mesh object."""
        return self._set_of(obj, "receiver_collection"), self._set_of(obj, "blocker_collection")

    def membership(self, obj) -> tuple[int, int]:
        """(light_sets, shadow_sets) bitmasks of an object (-1: every set)."""
        ptr = obj.original.as_pointer()
        masks = []
        for found in self._sets.values():
            mask = _ALL
            for index, included, excluded in found.values():
                if index and not ((ptr in included if included else True) and ptr not in excluded):
                    mask &= ~(1 << index)
            masks.append(mask)
        return masks[0], masks[1]
