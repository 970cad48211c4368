"""Monte's panels, where Cycles users look for them, and Blender's own panels opted in for Monte.

Render properties: Sampling (samples, sampler, seed, clamp, time limit, light sampling), Light Paths (max
bounces, Russian roulette depth), Film (pixel filter and width), Performance (threads, batch size, tiles),
Cluster (render on a Dask cluster, test the connection).
View layer properties: Passes (Depth, Normal, Albedo, Variance). Material, world and light properties: the
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


class MONTE_RENDER_PT_light_paths(MonteButtonsPanel, Panel):
    bl_label = "Light Paths"
    SCENE_PROPS = ("max_bounces", "rr_depth")


class MONTE_RENDER_PT_film(MonteButtonsPanel, Panel):
    bl_label = "Film"
    SCENE_PROPS = ("filter_type", "filter_width")


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


classes = (
    MONTE_RENDER_PT_sampling,
    MONTE_RENDER_PT_viewport,
    MONTE_RENDER_PT_light_paths,
    MONTE_RENDER_PT_film,
    MONTE_RENDER_PT_performance,
    MONTE_RENDER_PT_crosscheck,
    MONTE_RENDER_PT_cluster,
    MONTE_VIEWLAYER_PT_passes,
    MONTE_MATERIAL_PT_surface,
    MONTE_WORLD_PT_surface,
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
