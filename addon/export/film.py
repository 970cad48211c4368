"""Blender's film settings -> core Film: Film > Transparent, Transparent Glass and its roughness threshold
(Cycles' properties on `scene.render` and `scene.cycles`; the defaults where the Cycles add-on is absent)."""

from __future__ import annotations

from ...core.scene import Film


def export_film(scene) -> Film:
    """core Film of a Blender scene (see core.scene.Film for what each setting does)."""
    cycles = getattr(scene, "cycles", None)
    transparent = bool(scene.render.film_transparent)
    glass = bool(getattr(cycles, "film_transparent_glass", False)) if cycles is not None else False
    roughness = float(getattr(cycles, "film_transparent_roughness", 0.1)) if cycles is not None else 0.1
    return Film(transparent=transparent, transparent_glass=transparent and glass,
                transparent_roughness=min(max(roughness, 0.0), 1.0))
