"""Monte's panels, where Cycles users look for them, and Blender's own panels opted in for Monte.

Render properties: Sampling (samples, sampler, seed, clamp, time limit, light sampling), Viewport and Previews,
Denoise (on/off, quality, whether Open Image Denoise is installed), Light Paths (max bounces, Russian roulette
depth), Film (pixel filter and width, Transparent, Transparent Glass), Performance (threads, batch size, tiles),
Cluster (render on a Dask cluster, test the connection), Motion Blur (on/off, position, shutter, rolling shutter).
Camera properties: Panorama (a panoramic camera's type and settings). Object properties: Visibility (ray
visibility, holdout, shadow catcher), Motion Blur (on/off, Deformation, Steps).
View layer properties: Passes (Depth, Normal, Albedo, Variance; Data: Mist, Position, UV, Vector (warns), Object and
Material Index; Cryptomatte). World properties: Mist Pass. Material, world and light properties: the
node inputs Monte reads (the active output for Cycles/All) and the light settings Monte uses.
Blender's generic panels (those that list 'BLENDER_RENDER' in COMPAT_ENGINES: dimensions, output, camera
lens, colour management, ...) get 'MONTE' added, except the few that describe features Monte lacks.
"""

from __future__ import annotations

import bpy
from bpy.types import Panel

ENGINE = "MONTE"

# Generic panels that would show settings Monte does not use.
_EXCLUDED_PANELS = {
    "DATA_PT_light",  # replaced by MONTE_LIGHT_PT_light
    "NODE_DATA_PT_light",
    "DATA_PT_preview",  # no material/light previews (bl_use_preview = False)
    "DATA_PT_camera_dof",  # depth of field is not supported
    "DATA_PT_camera_dof_aperture",
    "RENDER_PT_simplify",
    "DATA_PT_lightprobe",
    "DATA_PT_lightprobe_display",
    "DATA_PT_lightprobe_visibility",
    "DATA_PT_lightprobe_parallax",
    "DATA_PT_context_lightprobe",
}
# Panels from EEVEE's set that fit Monte as they are.
_EXTRA_PANELS = {
    "EEVEE_MATERIAL_PT_context_material",
    "DATA_PT_spot",
}


def compat_panels() -> list[type]:
    panels = []
    for panel in bpy.types.Panel.__subclasses__():
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if not isinstance(engines, set):
            continue
        name = panel.__name__
        if name in _EXCLUDED_PANELS:
            continue
        if "BLENDER_RENDER" in engines or name in _EXTRA_PANELS:
            panels.append(panel)
    return panels


def split_layout(layout, decorate: bool = False):
    """`layout` with Blender's property-split look (labels left, values right)."""
    layout.use_property_split = True
    layout.use_property_decorate = decorate
    return layout


class MonteButtonsPanel:
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE}
    # The context member the panel is about (e.g. "material"): the panel shows only where it is set.
    CONTEXT_MEMBER = None
    # scene.monte properties the default draw() lists in one aligned column.
    SCENE_PROPS = ()

    @classmethod
    def poll(cls, context):
        if cls.CONTEXT_MEMBER is not None and getattr(context, cls.CONTEXT_MEMBER, None) is None:
            return False
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        col = split_layout(self.layout).column(align=True)
        for name in self.SCENE_PROPS:
            col.prop(context.scene.monte, name)


class MONTE_RENDER_PT_sampling(MonteButtonsPanel, Panel):
    bl_label = "Sampling"

    def draw(self, context):
        layout = split_layout(self.layout)
        monte = context.scene.monte
        col = layout.column(align=True)
        col.prop(monte, "samples")
        col.prop(monte, "time_limit")
        heading = layout.column(align=True, heading="Noise Threshold")
        row = heading.row(align=True)
        row.prop(monte, "use_adaptive_sampling", text="")
        sub = row.row()
        sub.active = monte.use_adaptive_sampling
        sub.prop(monte, "adaptive_threshold", text="")
        sub = layout.column(align=True)
        sub.active = monte.use_adaptive_sampling
        sub.prop(monte, "adaptive_min_samples")
        col = layout.column()
        col.prop(monte, "sampler")
        row = col.row(align=True)
        row.prop(monte, "seed")
        row.prop(monte, "use_animated_seed", text="", icon="TIME")
        col.prop(monte, "clamp")
        col.prop(monte, "light_sampling")


class MONTE_RENDER_PT_viewport(MonteButtonsPanel, Panel):
    bl_label = "Viewport and Previews"

    def draw(self, context):
        layout = split_layout(self.layout)
        scene = context.scene
        col = layout.column(align=True)
        col.prop(scene.monte, "viewport_samples")
        col.prop(scene.monte, "viewport_start_resolution")
        col.prop(scene.render, "preview_pixel_size", text="Pixel Size")


class MONTE_RENDER_PT_denoise(MonteButtonsPanel, Panel):
    bl_label = "Denoise"

    def draw_header(self, context):
        self.layout.prop(context.scene.monte, "use_denoising", text="")

    def draw(self, context):
        from ..core.denoise import denoiser_status

        layout = split_layout(self.layout)
        monte = context.scene.monte
        col = layout.column()
        col.active = monte.use_denoising
        col.label(text="Denoiser: OpenImageDenoise")
        col.prop(monte, "denoising_quality")
        reason = denoiser_status()
        if reason is not None:
            box = layout.box()
            box.label(text="Open Image Denoise is not available:", icon="ERROR")
            box.label(text="the render is saved without denoising.")
            box.label(text="Install pyoidn into Blender's Python (README: Denoising).")


class MONTE_RENDER_PT_light_paths(MonteButtonsPanel, Panel):
    bl_label = "Light Paths"
    SCENE_PROPS = ("max_bounces", "rr_depth")

    def draw(self, context):
        MonteButtonsPanel.draw(self, context)
        cycles = getattr(context.scene, "cycles", None)  # shared with Cycles' setting, as Monte reads it
        if cycles is not None and "transparent_max_bounces" in cycles.bl_rna.properties:
            split_layout(self.layout).prop(cycles, "transparent_max_bounces", text="Transparent Bounces")
        if cycles is not None and "min_transparent_bounces" in cycles.bl_rna.properties:
            split_layout(self.layout).prop(cycles, "min_transparent_bounces", text="Min Transparent Bounces")


class MONTE_RENDER_PT_film(MonteButtonsPanel, Panel):
    bl_label = "Film"
    SCENE_PROPS = ("filter_type", "filter_width")

    def draw(self, context):
        MonteButtonsPanel.draw(self, context)
        scene = context.scene
        col = split_layout(self.layout).column(heading="Transparent")
        col.prop(scene.render, "film_transparent", text="")
        cycles = getattr(scene, "cycles", None)  # Transparent Glass lives with Cycles' settings, as Monte reads it
        if cycles is not None and "film_transparent_glass" in cycles.bl_rna.properties:
            sub = col.column()
            sub.active = scene.render.film_transparent
            sub.prop(cycles, "film_transparent_glass", text="Transparent Glass")
            sub = sub.column()
            sub.active = scene.render.film_transparent and cycles.film_transparent_glass
            sub.prop(cycles, "film_transparent_roughness", text="Roughness Threshold")


class MONTE_CAMERA_PT_panorama(MonteButtonsPanel, Panel):
    """The panoramic camera's settings (Blender's Lens panel draws them for Cycles only)."""

    bl_label = "Panorama"
    bl_context = "data"
    CONTEXT_MEMBER = "camera"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.camera.type == "PANO"

    def draw(self, context):
        cam = context.camera
        col = split_layout(self.layout).column()
        col.prop(cam, "panorama_type")
        kind = cam.panorama_type
        if kind == "EQUIRECTANGULAR":
            sub = col.column(align=True)
            sub.prop(cam, "latitude_min", text="Latitude Min")
            sub.prop(cam, "latitude_max", text="Max")
            sub = col.column(align=True)
            sub.prop(cam, "longitude_min", text="Longitude Min")
            sub.prop(cam, "longitude_max", text="Max")
        elif kind == "FISHEYE_EQUIDISTANT":
            col.prop(cam, "fisheye_fov")
        elif kind == "FISHEYE_EQUISOLID":
            col.prop(cam, "fisheye_lens", text="Lens")
            col.prop(cam, "fisheye_fov")
        elif kind == "FISHEYE_LENS_POLYNOMIAL":
            col.prop(cam, "fisheye_fov")
            for i in range(5):
                col.prop(cam, f"fisheye_polynomial_k{i}", text=f"K{i}")
        elif kind == "CENTRAL_CYLINDRICAL":
            sub = col.column(align=True)
            sub.prop(cam, "central_cylindrical_range_v_min", text="Height Min")
            sub.prop(cam, "central_cylindrical_range_v_max", text="Max")
            sub = col.column(align=True)
            sub.prop(cam, "central_cylindrical_range_u_min", text="Longitude Min")
            sub.prop(cam, "central_cylindrical_range_u_max", text="Max")
            col.prop(cam, "central_cylindrical_radius", text="Cylinder Radius")


class MONTE_OBJECT_PT_visibility(MonteButtonsPanel, Panel):
    """Ray visibility, holdout and shadow catcher (Cycles' object visibility settings, which Monte reads)."""

    bl_label = "Visibility"
    bl_context = "object"
    CONTEXT_MEMBER = "object"

    def draw(self, context):
        ob = context.object
        layout = split_layout(self.layout)
        col = layout.column(heading="Ray Visibility", align=True)
        for name, text in (("visible_camera", "Camera"), ("visible_diffuse", "Diffuse"),
                           ("visible_glossy", "Glossy"), ("visible_transmission", "Transmission"),
                           ("visible_volume_scatter", "Volume Scatter"), ("visible_shadow", "Shadow")):
            col.prop(ob, name, text=text)
        col = layout.column(heading="Mask", align=True)
        col.prop(ob, "is_shadow_catcher")
        col.prop(ob, "is_holdout")


class MONTE_OBJECT_PT_light_linking(MonteButtonsPanel, Panel):
    """Light Linking and Shadow Linking (Blender 4.0+; on a light or an emissive mesh): the receiver and blocker
    collections Monte renders, edited with Blender's own operators and list, as Cycles' panel does."""

    bl_label = "Light Linking"
    bl_context = "object"
    bl_options = {"DEFAULT_CLOSED"}
    CONTEXT_MEMBER = "object"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and hasattr(context.object, "light_linking")

    def draw(self, context):
        linking = context.object.light_linking
        for attr, kind, label in (("receiver_collection", "receiver", "Light Linking"),
                                  ("blocker_collection", "blocker", "Shadow Linking")):
            col = self.layout.column()
            col.label(text=label)
            row = col.row()
            row.template_ID(linking, attr, new=f"object.light_linking_{kind}_collection_new")
            if getattr(linking, attr) is not None:
                col.template_light_linking_collection(row, linking, attr)


class MONTE_RENDER_PT_motion_blur(MonteButtonsPanel, Panel):
    """Render > Motion Blur: the settings Cycles reads, which Monte renders (position, shutter, rolling shutter,
    shutter curve)."""

    bl_label = "Motion Blur"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_header(self, context):
        self.layout.prop(context.scene.render, "use_motion_blur", text="")

    def draw(self, context):
        scene = context.scene
        r = scene.render
        col = split_layout(self.layout).column()
        col.active = r.use_motion_blur
        col.prop(r, "motion_blur_position", text="Position")
        col.prop(r, "motion_blur_shutter")
        cycles = getattr(scene, "cycles", None)
        if cycles is not None and "rolling_shutter_type" in cycles.bl_rna.properties:
            col.prop(cycles, "rolling_shutter_type", text="Rolling Shutter")
            sub = col.column()
            sub.active = cycles.rolling_shutter_type != "NONE"
            sub.prop(cycles, "rolling_shutter_duration")
        self.layout.template_curve_mapping(r, "motion_blur_shutter_curve")


class MONTE_OBJECT_PT_motion_blur(MonteButtonsPanel, Panel):
    """Object > Motion Blur: Cycles' per-object settings (Motion Blur on/off, Deformation, Steps)."""

    bl_label = "Motion Blur"
    bl_context = "object"
    bl_options = {"DEFAULT_CLOSED"}
    CONTEXT_MEMBER = "object"

    @classmethod
    def poll(cls, context):  # every object: an instancer's settings apply to its instances too
        return super().poll(context) and getattr(context.object, "cycles", None) is not None

    def draw_header(self, context):
        self.layout.active = context.scene.render.use_motion_blur
        self.layout.prop(context.object.cycles, "use_motion_blur", text="")

    def draw(self, context):
        settings = context.object.cycles
        col = split_layout(self.layout).column()
        col.active = context.scene.render.use_motion_blur and settings.use_motion_blur
        if context.object.type not in ("CAMERA", "EMPTY"):
            col.prop(settings, "use_deform_motion", text="Deformation")
        col.prop(settings, "motion_steps", text="Steps")


class MONTE_RENDER_PT_performance(MonteButtonsPanel, Panel):
    bl_label = "Performance"
    bl_options = {"DEFAULT_CLOSED"}
    SCENE_PROPS = ("threads", "batch_paths", "tile_size")


class MONTE_RENDER_PT_crosscheck(MonteButtonsPanel, Panel):
    bl_label = "Cross-check"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.label(text="Render this frame with Cycles too and compare")
        layout.operator("monte.crosscheck", icon="IMAGE")


class MONTE_RENDER_PT_cluster(MonteButtonsPanel, Panel):
    bl_label = "Cluster"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_header(self, context):
        self.layout.prop(context.scene.monte, "use_cluster", text="")

    def draw(self, context):
        layout = split_layout(self.layout)
        monte = context.scene.monte
        col = layout.column()
        col.prop(monte, "use_cluster")
        sub = col.column()
        sub.active = monte.use_cluster
        sub.prop(monte, "cluster_address")
        sub.prop(monte, "cluster_timeout")
        layout.operator("monte.cluster_test", icon="NETWORK_DRIVE")
        if monte.cluster_status:
            layout.label(text=monte.cluster_status, icon="ERROR" if monte.cluster_status.startswith("Failed")
                         else "CHECKMARK")


class MONTE_VIEWLAYER_PT_passes(MonteButtonsPanel, Panel):
    bl_label = "Passes"
    bl_context = "view_layer"

    def draw(self, context):
        layout = split_layout(self.layout)
        view_layer = context.view_layer
        col = layout.column(heading="Include", align=True)
        col.prop(view_layer, "use_pass_combined")
        col.prop(view_layer, "use_pass_z")
        col.prop(view_layer, "use_pass_normal")
        col.prop(view_layer.monte, "use_pass_albedo")
        col.prop(view_layer.monte, "use_pass_variance")
        cycles = getattr(view_layer, "cycles", None)  # Cycles' own property (its add-on registers it)
        if cycles is not None and hasattr(cycles, "use_pass_shadow_catcher"):
            col.prop(cycles, "use_pass_shadow_catcher")


class MONTE_VIEWLAYER_PT_passes_data(MonteButtonsPanel, Panel):
    """Cycles' data passes (core.data_passes), with Blender's own view layer flags as Cycles shows them."""

    bl_label = "Data"
    bl_context = "view_layer"
    bl_parent_id = "MONTE_VIEWLAYER_PT_passes"

    def draw(self, context):
        layout = split_layout(self.layout)
        view_layer = context.view_layer
        col = layout.column(heading="Include", align=True)
        col.prop(view_layer, "use_pass_mist")
        col.prop(view_layer, "use_pass_position")
        col.prop(view_layer, "use_pass_uv")
        row = col.row()
        row.prop(view_layer, "use_pass_vector")
        if view_layer.use_pass_vector:
            from .engine import vector_unavailable

            why = vector_unavailable(view_layer, context.scene)
            if why:
                layout.label(text=why[0].upper() + why[1:], icon="ERROR")
        col = layout.column(heading="Indexes", align=True)
        col.prop(view_layer, "use_pass_object_index")
        col.prop(view_layer, "use_pass_material_index")


class MONTE_VIEWLAYER_PT_passes_cryptomatte(MonteButtonsPanel, Panel):
    bl_label = "Cryptomatte"
    bl_context = "view_layer"
    bl_parent_id = "MONTE_VIEWLAYER_PT_passes"

    def draw(self, context):
        layout = split_layout(self.layout)
        view_layer = context.view_layer
        col = layout.column(heading="Include", align=True)
        col.prop(view_layer, "use_pass_cryptomatte_object", text="Object")
        col.prop(view_layer, "use_pass_cryptomatte_material", text="Material")
        col.prop(view_layer, "use_pass_cryptomatte_asset", text="Asset")
        layout.prop(view_layer, "pass_cryptomatte_depth", text="Levels")


class MONTE_VIEWLAYER_PT_passes_light(MonteButtonsPanel, Panel):
    """Cycles' light passes, with Cycles' own view layer checkboxes (addon.engine.LIGHT_PASS_PROPERTIES)."""

    bl_label = "Light"
    bl_context = "view_layer"
    bl_parent_id = "MONTE_VIEWLAYER_PT_passes"

    def draw(self, context):
        layout = split_layout(self.layout)
        view_layer = context.view_layer
        for heading, kind in (("Diffuse", "diffuse"), ("Glossy", "glossy"), ("Transmission", "transmission")):
            col = layout.column(heading=heading, align=True)
            col.prop(view_layer, f"use_pass_{kind}_direct", text="Direct")
            col.prop(view_layer, f"use_pass_{kind}_indirect", text="Indirect")
            col.prop(view_layer, f"use_pass_{kind}_color", text="Color")
        col = layout.column(heading="Other", align=True)
        col.prop(view_layer, "use_pass_emit", text="Emission")
        col.prop(view_layer, "use_pass_environment")


class MONTE_VIEWLAYER_PT_passes_aov(MonteButtonsPanel, Panel):
    """Cycles' Shader AOV list (Blender's own view layer AOVs and operators; core.shader_aovs)."""

    bl_label = "Shader AOV"
    bl_context = "view_layer"
    bl_parent_id = "MONTE_VIEWLAYER_PT_passes"

    def draw(self, context):
        layout = split_layout(self.layout)
        view_layer = context.view_layer
        row = layout.row()
        row.column().template_list("VIEWLAYER_UL_aov", "aovs", view_layer, "aovs", view_layer, "active_aov_index",
                                   rows=3)
        sub = row.column().column(align=True)
        sub.operator("scene.view_layer_add_aov", icon="ADD", text="")
        sub.operator("scene.view_layer_remove_aov", icon="REMOVE", text="")
        aov = view_layer.active_aov
        if aov is not None and not aov.is_valid:
            layout.label(text="Conflicts with another render pass with the same name", icon="ERROR")


class MONTE_VIEWLAYER_PT_light_groups(MonteButtonsPanel, Panel):
    """Cycles' Light Groups list (Blender's own view layer light groups and operators; core.light_groups): each
    group is a Combined_<name> pass."""

    bl_label = "Light Groups"
    bl_context = "view_layer"
    bl_parent_id = "MONTE_VIEWLAYER_PT_passes"

    def draw(self, context):
        view_layer = context.view_layer
        row = self.layout.row()
        row.column().template_list("UI_UL_list", "lightgroups", view_layer, "lightgroups", view_layer,
                                   "active_lightgroup_index", rows=3)
        sub = row.column(align=True)
        sub.operator("scene.view_layer_add_lightgroup", icon="ADD", text="")
        sub.operator("scene.view_layer_remove_lightgroup", icon="REMOVE", text="")
        sub.separator()
        sub.operator("scene.view_layer_add_used_lightgroups", icon="ADD", text="")
        sub.operator("scene.view_layer_remove_unused_lightgroups", icon="REMOVE", text="")


def _draw_light_group(layout, owner, view_layer) -> None:
    """An emitter's Light Group: chosen among the view layer's groups (a name not among them lights no group)."""
    layout = split_layout(layout)
    layout.prop_search(owner, "lightgroup", view_layer, "lightgroups", text="Light Group",
                       results_are_suggestions=True)


class MONTE_OBJECT_PT_light_group(MonteButtonsPanel, Panel):
    """Object > Shading > Light Group of a light or an emissive mesh (core.light_groups)."""

    bl_label = "Light Group"
    bl_context = "object"
    bl_options = {"DEFAULT_CLOSED"}
    CONTEXT_MEMBER = "object"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and hasattr(context.object, "lightgroup")

    def draw(self, context):
        _draw_light_group(self.layout, context.object, context.view_layer)


class MONTE_WORLD_PT_light_group(MonteButtonsPanel, Panel):
    """World > Settings > Light Group (core.light_groups)."""

    bl_label = "Light Group"
    bl_context = "world"
    bl_options = {"DEFAULT_CLOSED"}
    CONTEXT_MEMBER = "world"

    def draw(self, context):
        _draw_light_group(self.layout, context.world, context.view_layer)


def _draw_node_input(layout, tree, input_name: str) -> None:
    output = tree.get_output_node("CYCLES") if tree is not None else None
    if output is None:
        layout.label(text="No output node")
        return
    sock = output.inputs.get(input_name)
    if sock is None:
        layout.label(text="Incompatible output node")
        return
    layout.template_node_view(tree, output, sock)


class MONTE_WORLD_PT_mist(MonteButtonsPanel, Panel):
    """World > Mist Pass, shown as Cycles shows it: while the view layer has the Mist pass on."""

    bl_label = "Mist Pass"
    bl_context = "world"

    @classmethod
    def poll(cls, context):
        return (super().poll(context) and context.world is not None and context.view_layer is not None
                and context.view_layer.use_pass_mist)

    def draw(self, context):
        layout = split_layout(self.layout)
        mist = context.world.mist_settings
        col = layout.column(align=True)
        col.prop(mist, "start")
        col.prop(mist, "depth")
        layout.prop(mist, "falloff")


class MONTE_MATERIAL_PT_surface(MonteButtonsPanel, Panel):
    bl_label = "Surface"
    bl_context = "material"
    CONTEXT_MEMBER = "material"

    def draw(self, context):
        layout = split_layout(self.layout, decorate=True)
        mat = context.material
        if mat.node_tree is None:
            layout.prop(mat, "diffuse_color", text="Color")
            return
        _draw_node_input(layout, mat.node_tree, "Surface")


class MONTE_WORLD_PT_surface(MonteButtonsPanel, Panel):
    bl_label = "Surface"
    bl_context = "world"
    CONTEXT_MEMBER = "world"

    def draw(self, context):
        layout = split_layout(self.layout, decorate=True)
        world = context.world
        if world.node_tree is None:
            layout.prop(world, "color")
            return
        _draw_node_input(layout, world.node_tree, "Surface")


class MONTE_LIGHT_PT_light(MonteButtonsPanel, Panel):
    bl_label = "Light"
    bl_context = "data"
    CONTEXT_MEMBER = "light"

    def draw(self, context):
        layout = self.layout
        light = context.light
        layout.row().prop(light, "type", expand=True)
        col = split_layout(layout).column()
        col.prop(light, "color")
        if "use_temperature" in light.bl_rna.properties:  # Blender 4.5+
            row = col.row(heading="Temperature")
            row.prop(light, "use_temperature", text="")
            sub = row.row()
            sub.active = light.use_temperature
            sub.prop(light, "temperature", text="")
        col.prop(light, "energy")
        if "exposure" in light.bl_rna.properties:  # Blender 4.5+
            col.prop(light, "exposure")
        col.separator()
        if light.type in {"POINT", "SPOT"}:
            col.prop(light, "shadow_soft_size", text="Radius")
        elif light.type == "SUN":
            col.prop(light, "angle")
        elif light.type == "AREA":
            col.prop(light, "shape")
            sub = col.column(align=True)
            if light.shape in {"SQUARE", "DISK"}:
                sub.prop(light, "size")
            else:
                sub.prop(light, "size", text="Size X")
                sub.prop(light, "size_y", text="Y")
            col.prop(light, "spread")
            if "normalize" in light.bl_rna.properties:  # Blender 4.5+
                col.prop(light, "normalize")
            # Cycles' light portal (on light.cycles in Blender 4.x-5.x): guides the world's sampling
            owner = light if "is_portal" in light.bl_rna.properties else getattr(light, "cycles", None)
            if owner is not None and "is_portal" in owner.bl_rna.properties:
                col.prop(owner, "is_portal", text="Portal")


classes = (
    MONTE_RENDER_PT_sampling,
    MONTE_RENDER_PT_viewport,
    MONTE_RENDER_PT_denoise,
    MONTE_RENDER_PT_light_paths,
    MONTE_RENDER_PT_film,
    MONTE_CAMERA_PT_panorama,
    MONTE_OBJECT_PT_visibility,
    MONTE_OBJECT_PT_light_linking,
    MONTE_RENDER_PT_motion_blur,
    MONTE_OBJECT_PT_motion_blur,
    MONTE_RENDER_PT_performance,
    MONTE_RENDER_PT_crosscheck,
    MONTE_RENDER_PT_cluster,
    MONTE_VIEWLAYER_PT_passes,
    MONTE_VIEWLAYER_PT_passes_data,
    MONTE_VIEWLAYER_PT_passes_cryptomatte,
    MONTE_VIEWLAYER_PT_passes_light,
    MONTE_VIEWLAYER_PT_passes_aov,
    MONTE_VIEWLAYER_PT_light_groups,
    MONTE_OBJECT_PT_light_group,
    MONTE_WORLD_PT_light_group,
    MONTE_MATERIAL_PT_surface,
    MONTE_WORLD_PT_surface,
    MONTE_WORLD_PT_mist,
    MONTE_LIGHT_PT_light,
)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    for panel in compat_panels():
        panel.COMPAT_ENGINES.add(ENGINE)


def unregister() -> None:
    for panel in compat_panels():
        panel.COMPAT_ENGINES.discard(ENGINE)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
