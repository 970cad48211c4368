"""Blender's film settings -> core Film: Film > Transparent, Transparent Glass and its roughness threshold
(Cycles' properties on `scene.render` and `scene.cycles`; the defaults where the Cycles add-on is absent), and
whether the view layer asks for the Shadow Catcher pass (which changes how Combined is formed with a shadow
catcher, as in Cycles)."""

from __future__ import annotations

from ...core.scene import Film


def export_film(scene, view_layer=None) -> Film:
    """core Film of a Blender scene (see core.scene.Film for what each setting does). view_layer: the one being
    rendered (its Passes > Light > Shadow Catcher); None (the viewport) renders Cycles' approximate catcher, as
    Cycles' viewport does."""
    cycles = getattr(scene, "cycles", None)
    transparent = bool(scene.render.film_transparent)
    glass = bool(getattr(cycles, "film_transparent_glass", False)) if cycles is not None else False
    roughness = float(getattr(cycles, "film_transparent_roughness", 0.1)) if cycles is not None else 0.1
    return Film(transparent=transparent, transparent_glass=transparent and glass,
                transparent_roughness=min(max(roughness, 0.0), 1.0),
                shadow_catcher_pass=uses_shadow_catcher_pass(view_layer))


def uses_shadow_catcher_pass(view_layer) -> bool:
    """Whether the view layer asks for the Shadow Catcher pass (Cycles' view layer property; False where the
    Cycles add-on is absent)."""
    cycles = getattr(view_layer, "cycles", None) if view_layer is not None else None
    return bool(getattr(cycles, "use_pass_shadow_catcher", False))
