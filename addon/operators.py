"""Monte's operators: the Cycles cross-check from the render panel (Render Properties > Cross-check)."""

from __future__ import annotations

import os
from pathlib import Path

import bpy
from bpy.props import IntProperty, StringProperty

DIFFERENCE_IMAGE = "Monte Cross-check"


class MONTE_OT_crosscheck(bpy.types.Operator):
    """Render the current frame with Monte and with Cycles and compare them: shows the difference image
    (per-pixel z-scores) and reports whether they agree within noise"""

    bl_idname = "monte.crosscheck"
    bl_label = "Cross-check with Cycles"
    bl_options = {"REGISTER"}

    directory: StringProperty(
        name="Output Folder", subtype="DIR_PATH",
        description="Where monte.exr, cycles.exr, difference.png and report.json/.txt go "
        "(empty: a 'monte-crosscheck' folder in Blender's temporary directory)", default="",
    )
    cycles_samples: IntProperty(
        name="Cycles Samples", description="Cycles' samples per pixel in total, over 4 seeds (0 = Monte's)",
        default=0, min=0,
    )
    threads: IntProperty(name="Threads", description="Threads for both renderers (0 = all cores)", default=0,
                         min=0)

    @classmethod
    def poll(cls, context):
        return context.scene is not None and context.scene.camera is not None

    def execute(self, context):
        from .crosscheck import CrosscheckError, CrosscheckOptions, crosscheck_scene

        scene = context.scene
        folder = bpy.path.abspath(self.directory) if self.directory else os.path.join(
            bpy.app.tempdir or "/tmp", "monte-crosscheck")
        options = CrosscheckOptions(cycles_spp=self.cycles_samples or None, threads=self.threads)
        try:
            report = crosscheck_scene(scene, folder, options, log=lambda m: print(m, flush=True))
        except (CrosscheckError, ValueError, OSError) as exc:
            self.report({"ERROR"}, f"Monte cross-check: {exc}")
            return {"CANCELLED"}
        image = _load_difference(Path(folder) / "difference.png")
        _show_in_image_editor(context, image)
        verdict = report["verdict"]
        rel = ", ".join(f"{100 * report['relative_difference'][c]:+.2f}" for c in "RGB")
        if verdict["agree"]:
            self.report({"INFO"}, f"Monte and Cycles agree within noise (mean difference R,G,B {rel} %); "
                                  f"report in {folder}")
        else:
            self.report({"WARNING"}, "Monte and Cycles disagree: " + "; ".join(verdict["reasons"])
                        + f" - see {os.path.join(folder, 'report.txt')}")
        return {"FINISHED"}


def _load_difference(path: Path):
    image = bpy.data.images.get(DIFFERENCE_IMAGE)
    if image is not None:
        bpy.data.images.remove(image)
    image = bpy.data.images.load(str(path), check_existing=False)
    image.name = DIFFERENCE_IMAGE
    image.pack()  # the file may be overwritten by the next cross-check; the datablock keeps this one
    return image


def _show_in_image_editor(context, image) -> None:
    screen = getattr(context, "screen", None)
    if screen is None:  # background mode: no windows
        return
    for area in screen.areas:
        if area.type == "IMAGE_EDITOR":
            area.spaces.active.image = image
            area.tag_redraw()
            return


classes = (MONTE_OT_crosscheck,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
