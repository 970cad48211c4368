"""Not a test module: bpy code, as text, that builds the smallest scene with a known image, for tests that run
Blender in a fresh process (the extension install test, the headless exit tests).

PLANE_SCENE builds, in Blender's current file, a diffuse plane of albedo 0.5 under a uniform white world seen
from 1 m above (camera `cam`, optional: the variable `with_camera` must be defined before it runs). With the
uniform world left to BSDF sampling every sample is exactly albedo x world, so the image is 0.5 to float32
precision. It uses plain bpy only (no Monte), and works on every Blender of the support table.
"""

import textwrap

PLANE_SCENE = textwrap.dedent(r"""
    scene = bpy.context.scene
    mat = bpy.data.materials.new("grey")
    mat.use_nodes = True  # before Blender 5.0 a new material has no node tree
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    dif = tree.nodes.new("ShaderNodeBsdfDiffuse")
    dif.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    tree.links.new(dif.outputs[0], out.inputs["Surface"])
    s = 1000.0
    me = bpy.data.meshes.new("plane")
    me.from_pydata([(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [], [(0, 1, 2, 3)])
    me.materials.append(mat)
    scene.collection.objects.link(bpy.data.objects.new("plane", me))
    if with_camera:
        cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
        cam.location = (0, 0, 1)
        scene.collection.objects.link(cam)
        scene.camera = cam
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True  # before Blender 5.0 a new world has no node tree
    scene.world = world
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
""")
