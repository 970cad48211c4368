"""Blender world -> core World: a uniform background (radiance colour x strength) or an environment map.

Supported: the active World Output's Surface linked to a Background node whose Color is unlinked (uniform) or
linked to an Environment Texture (equirectangular or mirror ball, Linear or Closest interpolation; Cubic and
Smart read as Linear with a warning) whose Vector is unlinked or comes from a Mapping node (rotation and scale;
location ignored, as for any direction) fed by Texture Coordinate Generated (or nothing), possibly through a Mix
(Color, Multiply) with a constant colour. The image's pixels come
through bpy (packed or on disk, its colour space applied); Strength multiplies it. Cycles' world sampling
settings (`world.cycles.sampling_method`, `sample_map_resolution`) choose the importance map's resolution.
Any other graph on the Background's Color or Strength (Gradient, Noise, Color Ramp, Mix, Layer Weight, ...) is
compiled as a node program (the material compiler) and baked over directions into an equirectangular map
(core.world_program: Cycles' background context), which lights the scene and is what escaping rays see; Is Camera
Ray read in it gives a camera-only map (World.camera_environment). A graph holding an Environment or Sky Texture
elsewhere than directly on the Background warns and falls back to the socket's colour; an Image Texture directly
on the colour -> its average colour (warned); a missing or unreadable image -> the Background's own colour. A Sky Texture (Preetham, Hosek-Wilkie,
Single Scattering / Nishita, Multiple Scattering: core.sky) is baked into an equirectangular environment map, a
scattering sky's sun disc made a sun light; a type not built warns by name and renders the socket's colour. No node tree: the world's viewport colour; no world at all: black. The Light Path trick of a
backdrop that differs from the light (a Mix Shader of two Backgrounds by Is Camera Ray) gives the world a
camera-only colour or map (core World.camera_color / camera_environment).
"""

from __future__ import annotations

import numpy as np

from ...core.scene import Mist, World
from ...core.world import EnvironmentMap
from .material import follow_link, image_average_color, image_pixels, node_tree, socket_value

_INTERPOLATION = {"Linear": "LINEAR", "Closest": "CLOSEST", "Cubic": "LINEAR", "Smart": "LINEAR"}


def export_world(world, warnings: list[str]) -> World:
    if world is None:
        return World(np.zeros(3))
    name = world.name
    visibility = getattr(world, "cycles_visibility", None)
    if visibility is not None:
        off = [label for prop, label in (("camera", "Camera"), ("diffuse", "Diffuse"), ("glossy", "Glossy"),
                                         ("transmission", "Transmission"), ("scatter", "Volume Scatter"))
               if not getattr(visibility, prop, True)]
        if off:
            warnings.append(f"world {name!r}: Ray Visibility {', '.join(off)} off is not supported; the world is "
                            "seen by every ray")
    tree = node_tree(world)
    if tree is None:
        return World(np.array(world.color[:3], dtype=np.float64))
    output = tree.get_output_node("CYCLES")
    if output is None:
        warnings.append(f"world {name!r}: no active World Output node; the background is black")
        return World(np.zeros(3))
    volume = output.inputs.get("Volume")
    if volume is not None and volume.is_linked:
        warnings.append(f"world {name!r}: world volumes are not supported; the volume shader is ignored")
    surface = output.inputs.get("Surface")
    node = follow_link(surface)
    if node is None:
        return World(np.zeros(3))
    backdrop = _camera_backdrop(node, world, name, warnings)
    if backdrop is not None:
        return backdrop
    if node.bl_idname in _SHADER_MIXES and _only_backgrounds(node):
        programmed = _program_world(node, world, name, warnings)
        if programmed is not None:
            return programmed
    return _background_world(node, world, name, warnings)


_SHADER_MIXES = ("ShaderNodeMixShader", "ShaderNodeAddShader")


def _only_backgrounds(node, depth: int = 0) -> bool:
    """Whether the shader tree at `node` is Mix / Add Shaders of Background nodes (or nothing) alone."""
    if depth > 32:
        return False
    if node.bl_idname == "ShaderNodeBackground":
        return True
    if node.bl_idname not in _SHADER_MIXES:
        return False
    socks = node.inputs[1:3] if node.bl_idname == "ShaderNodeMixShader" else node.inputs[0:2]
    return all(src is None or _only_backgrounds(src, depth + 1) for src in (follow_link(sk) for sk in socks))


def _camera_backdrop(mix, world, name: str, warnings: list[str]) -> World | None:
    """The Light Path > Is Camera Ray trick: a Mix Shader whose factor is Is Camera Ray, of two Backgrounds (or
    nothing: black): the first lights the scene, the second is what the camera sees (uniform, or a map:
    World.camera_environment; a sun disc of a Sky Texture seen only by the camera is not drawn). None for any
    other surface."""
    if mix.bl_idname != "ShaderNodeMixShader" or not mix.inputs[0].is_linked:
        return None
    link = mix.inputs[0].links[0]
    if link.from_node.bl_idname != "ShaderNodeLightPath" or link.from_socket.name != "Is Camera Ray":
        return None
    shaders = [follow_link(mix.inputs[i]) for i in (1, 2)]
    if any(s is not None and s.bl_idname != "ShaderNodeBackground" for s in shaders):
        return None
    light, seen = (World(np.zeros(3)) if s is None else _background_world(s, world, name, warnings)
                   for s in shaders)
    if seen.lights:
        warnings.append(f"world {name!r}: the sun disc of a sky seen only by the camera (Light Path Is Camera Ray) "
                        "is not drawn")
    if seen.environment is not None:
        light.camera_environment = seen.environment
    else:
        light.camera_color = np.asarray(seen.color, np.float64)
    return light


def _background_world(node, world, name: str, warnings: list[str]) -> World:
    """The World of one Background node (or the documented fallbacks for another node)."""
    if node.bl_idname != "ShaderNodeBackground":
        warnings.append(f"world {name!r}: node {node.name!r} ({node.bl_label}) is not supported on the world "
                        "surface; using the world's viewport colour as a uniform background")
        return World(np.array(world.color[:3], dtype=np.float64))
    if _needs_program(node):
        programmed = _program_world(node, world, name, warnings)
        if programmed is not None:
            return programmed
    strength = float(socket_value(node.inputs["Strength"], f"world {name!r}", warnings))
    src = follow_link(node.inputs["Color"])
    factor = np.ones(3)
    if src is not None and src.bl_idname in ("ShaderNodeMix", "ShaderNodeMixRGB"):
        tex, factor = _constant_multiply(src)
        src = tex if tex is not None else src
    if src is not None and src.bl_idname == "ShaderNodeTexEnvironment":
        env = _environment(world, src, warnings)
        if env is not None:
            env.strength = np.maximum(factor * strength, 0.0)
            return World(np.zeros(3), environment=env)
        return World(np.maximum(np.array(node.inputs["Color"].default_value[:3], np.float64) * strength, 0.0))
    if src is not None and src.bl_idname == "ShaderNodeTexSky":
        sky, sun = _sky(world, src, warnings)
        if sky is not None:
            sky.strength = np.maximum(factor * strength, 0.0)
            if sun is not None:  # the sky's strength scales its sun too
                sun.strength = sun.strength * sky.strength
            return World(np.zeros(3), environment=sky, lights=[] if sun is None else [sun])
        return World(np.maximum(np.array(node.inputs["Color"].default_value[:3], np.float64) * strength, 0.0))
    color = _background_color(node.inputs["Color"], name, warnings)
    return World(np.maximum(color * strength, 0.0))


# Nodes a world program cannot express (their direct uses are the cases above): a graph holding one keeps the
# documented fallback.
_NOT_IN_PROGRAMS = {"ShaderNodeTexEnvironment": "Environment Texture", "ShaderNodeTexSky": "Sky Texture"}


def _needs_program(background) -> bool:
    """Whether the Background's Color or Strength is driven by a node graph none of the direct cases covers
    (uniform colour, Environment Texture, Sky Texture, an Image Texture's average, a constant Multiply of an
    Environment Texture; a Value node on Strength)."""
    strength = follow_link(background.inputs["Strength"])
    if strength is not None and strength.bl_idname != "ShaderNodeValue":
        return True
    src = follow_link(background.inputs["Color"])
    if src is None or src.bl_idname in ("ShaderNodeTexEnvironment", "ShaderNodeTexSky", "ShaderNodeTexImage"):
        return False
    if src.bl_idname in ("ShaderNodeMix", "ShaderNodeMixRGB") and _constant_multiply(src)[0] is not None:
        return False
    return True


def _upstream_node(node, kinds: dict, seen: set | None = None):
    """The first node of a type in `kinds` feeding `node` (through links, not into node groups), or None."""
    seen = set() if seen is None else seen
    for sock in node.inputs:
        for link in getattr(sock, "links", ()):
            src = link.from_node
            if src.as_pointer() in seen:
                continue
            seen.add(src.as_pointer())
            if src.bl_idname in kinds:
                return src
            found = _upstream_node(src, kinds, seen)
            if found is not None:
                return found
    return None


def _world_radiance(c, node, ctx, w: int, acc: int, depth: int = 0) -> int:
    """acc + w x the radiance of the world shader `node` (a Background: colour x strength; Mix / Add Shaders of
    them), as registers of the ProgramBuilder c."""
    from .nodes.compiler import FLOAT, RGBA, CompileError

    if depth > 32:
        raise CompileError("the world's shaders nest too deeply")
    kind = node.bl_idname
    if kind == "ShaderNodeBackground":
        return c.vmath("ADD", acc, c.vmath("SCALE", c.input(node, "Color", RGBA, ctx),
                                           scale=c.math("MULTIPLY", w, c.input(node, "Strength", FLOAT, ctx))))
    if kind not in _SHADER_MIXES:
        raise CompileError(f"node {node.name!r} ({node.bl_label}) is not supported on the world surface")
    if kind == "ShaderNodeMixShader":
        fac = c.math("MINIMUM", c.math("MAXIMUM", c.input(node, 0, FLOAT, ctx), c.const(0.0)), c.const(1.0))
        parts = ((node.inputs[1], c.math("MULTIPLY", w, c.math("SUBTRACT", c.const(1.0), fac))),
                 (node.inputs[2], c.math("MULTIPLY", w, fac)))
    else:
        parts = ((node.inputs[0], w), (node.inputs[1], w))
    for sock, weight in parts:
        found = c.source(sock, ctx)
        if found[0] != "default":
            acc = _world_radiance(c, found[1], found[3], weight, acc, depth + 1)
    return acc


def _program_world(background, world, name: str, warnings: list[str]) -> World | None:
    """The radiance of the world shader `background` (a Background's colour x strength, or Mix / Add Shaders of
    Backgrounds) compiled as a node program (the material compiler, Cycles' background shading context:
    core.world_program) and baked into an equirectangular environment map that lights the scene (importance
    sampled) and is what escaping rays see. None (warned) when the graph holds a node a program cannot express;
    the caller then falls back as documented."""
    from ...core.shading import registry as R
    from ...core.shading.program import RAY_CAMERA, RAY_DIFFUSE, RAY_REFLECT
    from ...core.world_program import bake_world_program
    from .material import image_rgba
    from .nodes.compiler import CompileError, Ctx, ProgramBuilder

    blocker = _upstream_node(background, _NOT_IN_PROGRAMS)
    if blocker is not None:
        warnings.append(f"world {name!r}: node {blocker.name!r} ({_NOT_IN_PROGRAMS[blocker.bl_idname]}) inside a "
                        "world node graph is not supported (only directly on the Background, or times a constant "
                        "colour)")
        return None
    owner = f"world {name!r}"
    textures: list = []
    by_image: dict = {}

    def image_texture(node, alpha_used):
        image = node.image
        if image is None:
            warnings.append(f"{owner}: image texture {node.name!r} has no image; using Cycles' missing-texture "
                            "colour (magenta)")
            return None, 0
        key = image.as_pointer()
        if key not in by_image:
            try:
                pixels, encoded = image_rgba(image, warnings)
            except Exception as exc:  # missing file, unreadable image
                warnings.append(f"{owner}: node {node.name!r}: image {image.name!r} could not be read ({exc}); "
                                "using Cycles' missing-texture colour (magenta)")
                return None, 0
            from ...core.scene import Texture

            textures.append(Texture(image.name, np.where(np.isfinite(pixels), pixels, np.float32(0))))
            by_image[key] = (len(textures) - 1, 2 if encoded else 0)
        return by_image[key]

    builder = ProgramBuilder(owner, warnings, textures, image_texture)
    try:
        emission = _world_radiance(builder, background, Ctx(), builder.const(1.0), builder.const(0.0))
        program = builder.finish(np.zeros((0, 6), np.int32), emission)
    except CompileError as exc:
        warnings.append(f"{owner}: the world's node graph could not be compiled ({exc}); falling back")
        return None
    program.validate(owner, 0, len(textures))
    texcoord = R.op("texture_coordinate")
    rows = program.code[program.code[:, 0] == R.OP_TEXCOORD] if len(program.code) else program.code
    if len(rows) and np.any(rows[:, [texcoord.slot("camera"), texcoord.slot("window")]] >= 0):
        warnings.append(f"{owner}: Texture Coordinate Camera / Window on the world are not supported; they read "
                        "the ray direction (Camera) and 0 (Window)")
    method = getattr(getattr(world, "cycles", None), "sampling_method", "AUTOMATIC")
    resolution = int(getattr(world.cycles, "sample_map_resolution", 1024)) if method == "MANUAL" else 0

    def as_map(pixels, label):
        return EnvironmentMap(pixels=pixels, projection="EQUIRECTANGULAR", interpolation="LINEAR",
                              matrix=np.eye(3), map_resolution=resolution, importance_sampling=method != "NONE",
                              name=f"{name}/{label}")

    pixels = bake_world_program(program, textures)  # the light: as a light sample sees it (no ray flags)
    got = World(np.zeros(3), environment=as_map(pixels, "program"))
    if len(program.code) and np.any(program.code[:, 0] == R.OP_LIGHT_PATH):
        # Is Camera Ray: the camera sees the program with the camera flag set (a backdrop that differs from the
        # light). The other outputs are those of a light sample (Cycles' BSDF rays that escape read their own).
        seen = bake_world_program(program, textures, path_flags=RAY_CAMERA)
        if not np.array_equal(seen, pixels):
            got.camera_environment = as_map(seen, "program (camera)")
        bounce = bake_world_program(program, textures, path_flags=RAY_DIFFUSE | RAY_REFLECT)
        if not np.array_equal(bounce, pixels):
            warnings.append(f"{owner}: Light Path outputs other than Is Camera Ray in the background's colour are "
                            "read as for a light sample (not a diffuse or glossy ray); the world lights the scene "
                            "as a light sample sees it")
    return got


# Sky types baked into an environment map (core.sky); the others warn by name and fall back.
_BAKED_SKY_TYPES = {"PREETHAM": "Preetham", "SINGLE_SCATTERING": "Single Scattering", "NISHITA": "Nishita",
                    "MULTIPLE_SCATTERING": "Multiple Scattering", "HOSEK_WILKIE": "Hosek-Wilkie"}


def _sky(world, tex, warnings: list[str]):
    """(EnvironmentMap, SunLight or None): a Sky Texture of a built type baked into an equirectangular map
    (strength 1) and, for the scattering models with Sun Disc on, its sun as a light (the disc is far smaller
    than the map's texels); (None, None) (warned) for the others (the caller falls back to the socket's
    colour)."""
    name = world.name
    kind = tex.sky_type
    if kind not in _BAKED_SKY_TYPES:
        label = kind.replace("_", " ").title().replace("Hosek Wilkie", "Hosek-Wilkie")
        warnings.append(f"world {name!r}: Sky Texture {tex.name!r} type {label!r} is not supported; using the "
                        "socket's own colour as a uniform background")
        return None, None
    matrix = _vector_matrix(tex.inputs["Vector"], name, warnings) if "Vector" in tex.inputs else np.eye(3)
    mapping = getattr(tex, "texture_mapping", None)
    if mapping is not None and (tuple(mapping.translation) != (0, 0, 0) or tuple(mapping.rotation) != (0, 0, 0)
                                or tuple(mapping.scale) != (1, 1, 1)):
        warnings.append(f"world {name!r}: Sky Texture {tex.name!r} texture mapping (its own Mapping panel) is "
                        "ignored")
    from ...core import sky as sky_model  # here, not at import: a render without a sky world never needs it

    sun_light = None
    if kind in ("PREETHAM", "HOSEK_WILKIE"):
        sun = np.array(tex.sun_direction[:3], np.float64)
        if not np.linalg.norm(sun) > 0:
            warnings.append(f"world {name!r}: Sky Texture {tex.name!r} sun direction is zero; using the zenith")
            sun = np.array([0.0, 0.0, 1.0])
        turbidity = float(tex.turbidity)
        if kind == "PREETHAM":
            pixels = sky_model.bake_equirectangular(lambda d: sky_model.preetham_radiance(d, sun, turbidity))
        else:
            albedo = float(tex.ground_albedo)
            pixels = sky_model.bake_equirectangular(
                lambda d: sky_model.hosek_wilkie_radiance(d, sun, turbidity, albedo))
    else:
        elevation, rotation = sky_model.wrap_sun_position(float(tex.sun_elevation), float(tex.sun_rotation))
        aerosol = float(getattr(tex, "aerosol_density", getattr(tex, "dust_density", 1.0)))
        altitude, air, ozone = float(tex.altitude), float(tex.air_density), float(tex.ozone_density)
        multiple = kind == "MULTIPLE_SCATTERING"
        make_lut = sky_model.multiple_scattering_lut if multiple else sky_model.single_scattering_lut
        lut = make_lut(elevation, altitude, air, aerosol, ozone)
        pixels = sky_model.bake_equirectangular(lambda d: sky_model.single_scattering_radiance(d, lut, rotation),
                                                2 * sky_model.SKY_BAKE_WIDTH if multiple else sky_model.SKY_BAKE_WIDTH)
        if tex.sun_disc:
            sun_light = sky_model.sun_disc_light(f"{name}/{tex.name} sun", elevation, rotation,
                                                 float(tex.sun_size), float(tex.sun_intensity), altitude, air,
                                                 aerosol, ozone, multiple_scattering=multiple)
            horizon = -sky_model.earth_horizon_dip(altitude) if multiple else 0.0
            if sun_light is not None and elevation - 0.5 * float(tex.sun_size) < horizon:
                warnings.append(f"world {name!r}: Sky Texture {tex.name!r} sun disc crosses the horizon; it is "
                                "rendered whole")
    method = getattr(getattr(world, "cycles", None), "sampling_method", "AUTOMATIC")
    resolution = int(getattr(world.cycles, "sample_map_resolution", 1024)) if method == "MANUAL" else 0
    env = EnvironmentMap(pixels=pixels, projection="EQUIRECTANGULAR", interpolation="LINEAR", matrix=matrix,
                         map_resolution=resolution, importance_sampling=method != "NONE",
                         name=f"{name}/{tex.name}")
    return env, sun_light


def _constant_multiply(mix) -> tuple[object | None, np.ndarray]:
    """(the Environment Texture, its constant colour factor) when `mix` is a Mix (Color, Multiply, unclamped
    result) of an Environment Texture and an unlinked colour with an unlinked factor f: mix(A, A x B, f) =
    A x ((1 - f) + f B). (None, ones) for anything else."""
    if mix.bl_idname == "ShaderNodeMix":
        if mix.data_type != "RGBA" or mix.clamp_result:
            return None, np.ones(3)
        fac = mix.inputs["Factor"] if mix.inputs[0].identifier != "Factor_Float" else mix.inputs[0]
        colours = [sk for sk in mix.inputs if sk.type == "RGBA" and sk.enabled]
    else:  # the legacy MixRGB node
        if getattr(mix, "use_clamp", False):
            return None, np.ones(3)
        fac, colours = mix.inputs["Fac"], [mix.inputs["Color1"], mix.inputs["Color2"]]
    if mix.blend_type != "MULTIPLY" or fac.is_linked or len(colours) != 2:
        return None, np.ones(3)
    f = min(max(float(fac.default_value), 0.0), 1.0)
    for tex_sock, const_sock in (colours, colours[::-1]):
        tex = follow_link(tex_sock)
        if tex is not None and tex.bl_idname == "ShaderNodeTexEnvironment" and not const_sock.is_linked:
            return tex, (1.0 - f) + f * np.array(const_sock.default_value[:3], np.float64)
    return None, np.ones(3)


def _environment(world, tex, warnings: list[str]) -> EnvironmentMap | None:
    """The Environment Texture as an EnvironmentMap (strength 1), or None (warned) when its image is missing or
    unreadable."""
    name = world.name
    image = tex.image
    if image is None:
        warnings.append(f"world {name!r}: environment texture {tex.name!r} has no image; using the Background's "
                        "own colour")
        return None
    path = image.filepath_from_user() if not image.packed_file else "<packed>"
    try:
        pixels = image_pixels(image, warnings)
    except (ValueError, RuntimeError) as exc:
        warnings.append(f"world {name!r}: environment image {image.name!r} ({path}) could not be read ({exc}); "
                        "using the Background's own colour")
        return None
    interpolation = _INTERPOLATION.get(tex.interpolation, "LINEAR")
    if tex.interpolation not in ("Linear", "Closest"):
        warnings.append(f"world {name!r}: environment texture {tex.name!r} interpolation {tex.interpolation!r} "
                        "is rendered as Linear")
    matrix = _vector_matrix(tex.inputs["Vector"], name, warnings)
    method = getattr(getattr(world, "cycles", None), "sampling_method", "AUTOMATIC")
    resolution = int(getattr(world.cycles, "sample_map_resolution", 1024)) if method == "MANUAL" else 0
    return EnvironmentMap(pixels=pixels, projection=tex.projection, interpolation=interpolation, matrix=matrix,
                          map_resolution=resolution, importance_sampling=method != "NONE",
                          name=f"{name}/{image.name}")


def _vector_matrix(sock, world_name: str, warnings: list[str]) -> np.ndarray:
    """The linear map from a world direction to the texture's lookup vector: identity for an unlinked Vector or
    Texture Coordinate Generated, a Mapping node's rotation and scale (Cycles' mapping types)."""
    src = follow_link(sock)
    if src is None:
        return np.eye(3)
    if src.bl_idname == "ShaderNodeTexCoord":
        return _coordinate_matrix(sock, src, world_name, warnings)
    if src.bl_idname != "ShaderNodeMapping":
        warnings.append(f"world {world_name!r}: node {src.name!r} ({src.bl_label}) driving the environment vector is "
                        "not supported; using the view direction")
        return np.eye(3)
    import mathutils

    def value(name):
        s = src.inputs.get(name)
        if s is None:
            return None
        if s.is_linked:
            warnings.append(f"world {world_name!r}: mapping {src.name!r} input {name!r} is linked, which is not "
                            "supported; using its own value")
        return np.array(s.default_value[:3], np.float64)

    rotation = value("Rotation")
    scale = value("Scale")
    location = value("Location")
    rot = np.array(mathutils.Euler(rotation.tolist(), "XYZ").to_matrix(), np.float64) if rotation is not None \
        else np.eye(3)
    kind = src.vector_type
    if kind == "POINT" and location is not None and np.any(location != 0):
        warnings.append(f"world {world_name!r}: mapping {src.name!r} location is ignored for a direction")
    s = scale if scale is not None else np.ones(3)
    if kind in ("POINT", "VECTOR"):
        m = rot @ np.diag(s)
    elif kind == "TEXTURE":
        safe = np.where(s != 0, s, 1.0)
        m = np.diag(np.where(s != 0, 1.0 / safe, 0.0)) @ rot.T
    else:  # NORMAL
        safe = np.where(s != 0, s, 1.0)
        m = rot @ np.diag(np.where(s != 0, 1.0 / safe, 0.0))
    inner = follow_link(src.inputs["Vector"])
    if inner is not None:
        if inner.bl_idname == "ShaderNodeTexCoord":
            m = m @ _coordinate_matrix(src.inputs["Vector"], inner, world_name, warnings)
        else:
            warnings.append(f"world {world_name!r}: node {inner.name!r} ({inner.bl_label}) feeding mapping "
                            f"{src.name!r} is not supported; using the view direction")
    return m


def _coordinate_matrix(sock, coord_node, world_name: str, warnings: list[str]) -> np.ndarray:
    link = sock.links[0]
    out = link.from_socket.name
    if out != "Generated":
        warnings.append(f"world {world_name!r}: texture coordinate {out!r} on the world is not supported; using "
                        "Generated (the view direction)")
    return np.eye(3)


def _background_color(sock, world_name: str, warnings: list[str]) -> np.ndarray:
    src = follow_link(sock)
    if src is None:
        return np.array(sock.default_value[:3], dtype=np.float64)
    if src.bl_idname == "ShaderNodeTexImage" and src.image is not None:
        avg = image_average_color(src.image)
        warnings.append(f"world {world_name!r}: texture {src.name!r} ({src.image.name}) on the background is "
                        f"not supported; using its average colour {np.round(avg, 4).tolist()}")
        return avg
    warnings.append(f"world {world_name!r}: node {src.name!r} ({src.bl_label}) driving the background colour is "
                    "not supported; using the socket's own colour")
    return np.array(sock.default_value[:3], dtype=np.float64)


def export_mist(world) -> Mist:
    """World > Mist Pass (start, depth, falloff) for the Mist pass; Blender's defaults without a world."""
    settings = getattr(world, "mist_settings", None)
    if settings is None:
        return Mist()
    return Mist(float(settings.start), float(settings.depth), str(settings.falloff))
