"""One reusable offscreen renderer per process: RGB, silhouette masks and depth of an object
seen from the cameras of ``sc3d_data.geometry.camera.ViewSettings``.

A small dedicated OpenGL path (PyOpenGL, one shader program), not pyrender's renderer: per
view pyrender spends ~8 ms of Python (scene traversal, uniform look-ups, one framebuffer
readback per view); here ALL views of an object are drawn into ONE framebuffer, an atlas of
``cols x rows`` tiles of ``S x S`` pixels, with one instanced draw call per mesh part
(``gl_InstanceID`` = view) and read back with one ``glReadPixels`` (plus one for depth when
asked for). Each instance's clip-space position is remapped onto its tile and clipped to it with
``gl_ClipDistance``, so a tile holds exactly what a separate ``S x S`` render would.
``draw`` submits an object's draws and flushes them, ``read`` reads the atlas back (``render``
does both): a caller with other work for the object (the render job voxelizes it) does it in
between, while a GPU draws, instead of waiting in ``glReadPixels``. The vertex data of all parts
of an object go into four buffers made once per renderer, one upload each per object, and each
part draws from its offsets there; parts that share a texture image (one material of a GLB used
by many meshes) upload it once per object.

Look: per mesh part, base colour = material colour factor x texture (sRGB -> linear, mipmapped;
textures over ``MAX_TEXTURE_SIZE`` are box-downscaled first) x vertex/face colours, as pyrender
reads them from trimesh; no material or texture -> grey 0.3. Emission is ignored. Matte
shading with a headlight: ``colour = base x (ambient + intensity x |n.l| / pi)`` then gamma 1/2.2 (pyrender's metallic-roughness shader without the specular term and without
metallic darkening), with flat per-pixel face normals (screen-space derivatives) and
two-sided lighting (most real meshes have inconsistent winding; culling is off). Objects are
opaque, except cut-outs: a part whose glTF material has ``alphaMode`` MASK (leaves, fences, hair
cards) draws only the fragments whose alpha (colour factor x texture x vertex colour alpha) is at
least its ``alphaCutoff`` (default 0.5), as glTF 2.0 says; the others are in neither image nor
mask. ``alphaMode`` BLEND is drawn opaque. No multisampling: the mask (alpha written by every fragment) and the RGB agree exactly,
and background pixels hold exactly the background colour.

Cameras: the shards store OpenCV ``K, R, t`` (world->camera, x right, y down, z forward);
``gl_view_matrices`` flips y and z to OpenGL camera axes and ``gl_projection`` builds the
projection from ``K`` as pyrender's ``IntrinsicsCamera`` does (masks are pixel-identical to the
former pyrender path; the tests project vertices with the stored K, R, t onto them). The OpenGL
context comes from pyrender's EGL/OSMesa platform classes; call
``sc3d_data.render.gl_backend.activate(backend)`` (done by ``MeshRenderer``) before anything imports
OpenGL, and never fork a process after a renderer exists.

Length: one module because the context, shaders, instanced draw and readback share one piece
of OpenGL state; split, each part would reach into the others' GL objects.
"""
from __future__ import annotations

import ctypes
import math
import os
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from sc3d_data.geometry.camera import ViewSettings
from sc3d_data.io.texture_wraps import REPEAT
from sc3d_data.render.gl_backend import activate

#: OpenCV camera axes -> OpenGL camera axes (flip y and z)
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
ZNEAR = 0.01
#: farthest point of the canonical cube [-0.5, 0.5]^3 from the origin, rounded up: no object
#: point is nearer a camera at distance d than d - this
_OBJECT_RADIUS = 1.0
DEFAULT_GREY = (0.3, 0.3, 0.3, 1.0)  # pyrender's colour for meshes without material
#: larger textures are box-downscaled by an integer factor to at most max(this, 8 x image size)
MAX_TEXTURE_SIZE = 1024


def opengl_camera_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Camera pose [4,4] (camera->world, OpenGL axes, as pyrender wants it) from OpenCV
    world->camera ``R [3,3]``, ``t [3]``."""
    pose = np.eye(4)
    pose[:3, :3] = R.T
    pose[:3, 3] = -R.T @ t
    return pose @ _CV_TO_GL


def gl_view_matrices(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """World -> OpenGL camera matrices ``[V,4,4]`` from OpenCV ``R [V,3,3]``, ``t [V,3]``."""
    V = np.zeros((len(R), 4, 4))
    V[:, :3, :3], V[:, :3, 3], V[:, 3, 3] = R, t, 1.0
    return _CV_TO_GL @ V


def depth_range(distance: float) -> tuple[float, float]:
    """``(znear, zfar)`` of the cameras at ``distance``. The 24-bit depth buffer's step at the
    object grows as distance^2 / znear: with znear fixed at ``ZNEAR`` it was 2.4e-5 at the default
    distance 2 but 0.02 at 60 and 6 units at 1000 (``--fov 0.1``, near-orthographic), so depth
    maps were off by units and surfaces drawn in the wrong order. znear grows with distance^2
    beyond 2 (the default's resolution everywhere, its bytes unchanged), and stays in front of
    the object (at most ``distance - 1``). Cameras passed to ``render`` explicitly share it."""
    znear = max(ZNEAR, min(ZNEAR * (distance / 2.0) ** 2, distance - _OBJECT_RADIUS))
    return znear, distance + 10.0


def gl_projection(K: np.ndarray, size: int, znear: float, zfar: float) -> np.ndarray:
    """OpenGL projection [4,4] for pinhole intrinsics ``K`` and a ``size x size`` image (as
    pyrender's ``IntrinsicsCamera``)."""
    P = np.zeros((4, 4))
    P[0, 0], P[0, 2] = 2.0 * K[0, 0] / size, 1.0 - 2.0 * K[0, 2] / size
    P[1, 1], P[1, 2] = 2.0 * K[1, 1] / size, 2.0 * K[1, 2] / size - 1.0
    P[2, 2], P[2, 3] = (zfar + znear) / (znear - zfar), 2.0 * zfar * znear / (znear - zfar)
    P[3, 2] = -1.0
    return P


#: prepended to both shaders: which optional varyings a program has (``_program``). A part
#: without vertex colours or without a texture gets a program without that varying: every
#: varying costs llvmpipe per-triangle set-up work (~10% of the draw call), and a constant
#: white colour or an unused uv changes no pixel.
_VARIANT_DEFINES = {"color": "#define HAS_COLOR\n", "texture": "#define HAS_TEXTURE\n",
                    "cutoff": "#define HAS_CUTOFF\n"}

_VERTEX = """
layout(location = 0) in vec3 position;
layout(location = 1) in vec4 color;
layout(location = 2) in vec2 texcoord;
uniform mat4 model;
uniform mat4 view[NVIEWS];
uniform mat4 proj;
uniform vec2 grid;  // cols, rows
out vec3 v_position;
#ifdef HAS_COLOR
out vec4 v_color;
#endif
#ifdef HAS_TEXTURE
out vec2 v_uv;
#endif
void main() {
    int i = gl_InstanceID;
    vec4 p = view[i] * (model * vec4(position, 1.0));
    vec4 c = proj * p;
    gl_ClipDistance[0] = c.w + c.x;
    gl_ClipDistance[1] = c.w - c.x;
    gl_ClipDistance[2] = c.w + c.y;
    gl_ClipDistance[3] = c.w - c.y;
    float col = float(i % int(grid.x));
    float row = grid.y - 1.0 - float(i / int(grid.x));  // view 0 in the top-left tile
    c.x = (c.x + c.w * (1.0 + 2.0 * col)) / grid.x - c.w;
    c.y = (c.y + c.w * (1.0 + 2.0 * row)) / grid.y - c.w;
    gl_Position = c;
    v_position = p.xyz;
#ifdef HAS_COLOR
    v_color = color;
#endif
#ifdef HAS_TEXTURE
    v_uv = texcoord;
#endif
}
"""

_FRAGMENT = """
in vec3 v_position;
#ifdef HAS_COLOR
in vec4 v_color;
#endif
#ifdef HAS_TEXTURE
in vec2 v_uv;
uniform sampler2D base_texture;
#endif
uniform vec4 base_color;
uniform float ambient;
uniform float diffuse;
#ifdef HAS_CUTOFF
uniform float alpha_cutoff;
#endif
out vec4 frag_color;
vec3 srgb_to_linear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), c));
}
void main() {
    vec3 base = base_color.rgb;
#ifdef HAS_TEXTURE
    vec4 texel = texture(base_texture, v_uv);
    base *= srgb_to_linear(texel.rgb);
#endif
#ifdef HAS_CUTOFF  // glTF alphaMode MASK: alpha = factor x texture x vertex colour
    float alpha = base_color.a;
#ifdef HAS_TEXTURE
    alpha *= texel.a;
#endif
#ifdef HAS_COLOR
    alpha *= v_color.a;
#endif
    if (alpha < alpha_cutoff) discard;
#endif
    vec3 n = normalize(cross(dFdx(v_position), dFdy(v_position)));
    vec3 c = base * (ambient + diffuse * abs(n.z));
#ifdef HAS_COLOR
    c *= v_color.rgb;
#endif
    frag_color = vec4(pow(clamp(c, 0.0, 1.0), vec3(1.0 / 2.2)), 1.0);
}
"""


@dataclass(frozen=True)
class RenderSettings:
    """How objects look: ``background`` RGB 0-255, ``depth`` (also return depth maps),
    ``light_intensity`` of the headlight (a directional light at the camera), ``ambient``
    light level (0-1). See the module doc for the shading model."""

    background: tuple[int, int, int] = (255, 255, 255)
    depth: bool = False
    light_intensity: float = 1.5
    ambient: float = 0.2
    shading: str = "matte-flat-headlight-v1"  # recorded in the shards' settings


def _color_factor(c) -> np.ndarray:
    """RGBA 0-1 from a trimesh colour (uint8 0-255 or float 0-1, RGB or RGBA; None = white)."""
    if c is None:
        return np.ones(4)
    c = np.asarray(c).ravel()
    c = c / 255.0 if c.dtype.kind in "ui" or c.max() > 1.0 else c.astype(np.float64)
    return np.concatenate([c, np.ones(4)])[:4]


def material_vertex_colors(visual, n: int) -> np.ndarray | None:
    """``[n, 4]`` uint8 RGBA vertex colours that multiply a material's colour (and texture), or
    None: a glTF primitive with both a material and ``COLOR_0``, which trimesh's loader keeps as
    the visual's ``vertex_attributes["color"]`` beside the material (glTF 2.0: base colour =
    ``baseColorFactor`` x texture x ``COLOR_0``). Floats are 0-1, unsigned bytes 0-255, unsigned
    shorts 0-65535 (the spec's normalised encodings); RGB gets alpha 1."""
    colors = getattr(visual, "vertex_attributes", {}).get("color")
    if colors is None or len(colors) != n:
        return None
    colors = np.asarray(colors)
    if colors.ndim != 2 or colors.shape[1] not in (3, 4):
        return None
    if colors.dtype.kind == "f":
        colors = np.rint(np.clip(colors, 0.0, 1.0) * 255.0)
    elif colors.dtype == np.uint16:
        colors = np.rint(colors / 257.0)
    colors = colors.astype(np.uint8)
    return colors if colors.shape[1] == 4 else np.concatenate([colors, np.full((n, 1), 255, np.uint8)], 1)


class MeshPart(NamedTuple):
    """One geometry of a scene, ready to draw (:func:`mesh_parts`).

    ``positions [N,3]`` float32 are the part's source-frame vertices less the centre of their
    bounding box (subtracted in float64), and ``model [4,4]`` maps them to the canonical frame
    (``to_canonical @ node transform @ translate(centre)``): a mesh far from its origin
    (georeferenced or CAD coordinates, 1e6 units away) keeps its shape in float32, which has 24
    bits of mantissa, and the model matrix's translation is the part's place in the canonical
    frame, near 0. ``faces [M,3]`` uint32; ``colors [N,4]`` uint8 RGBA or None; ``uv [N,2]``
    float32 and ``image`` (a PIL texture) both given or both None; ``base_color [4]`` RGBA 0-1;
    ``alpha_cutoff``: the material's ``alphaCutoff`` when its ``alphaMode`` is MASK, else None;
    ``wrap``: the texture's wrap modes along u and v, OpenGL's numbers (``io.texture_wraps``:
    REPEAT by default, glTF samplers' CLAMP_TO_EDGE and MIRRORED_REPEAT, an MTL ``-clamp on`` as
    CLAMP_TO_BORDER with a white border: the material's colour outside the texture)."""

    model: np.ndarray
    positions: np.ndarray
    faces: np.ndarray
    colors: np.ndarray | None
    uv: np.ndarray | None
    base_color: np.ndarray
    image: object
    alpha_cutoff: float | None
    wrap: tuple[int, int] = (REPEAT, REPEAT)


#: glTF 2.0's default ``alphaCutoff`` of an ``alphaMode`` MASK material
DEFAULT_ALPHA_CUTOFF = 0.5


def mesh_parts(scene, to_canonical: np.ndarray):
    """A :class:`MeshPart` per geometry of a ``trimesh.Scene``, with pyrender's reading of
    trimesh visuals (``to_canonical [4,4]``: source -> canonical frame)."""
    import trimesh

    from sc3d_data.io.loader_visuals import is_placeholder

    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        m = scene.geometry[name]
        if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
            continue
        model = np.asarray(to_canonical, dtype=np.float64) @ transform
        pos, faces = m.vertices, m.faces
        colors = uv = image = cutoff = None
        wrap = MeshPart._field_defaults["wrap"]
        base = np.array(DEFAULT_GREY)
        vis = m.visual
        if vis.defined and vis.kind == "vertex":
            colors, base = vis.vertex_colors, np.ones(4)
        elif vis.defined and vis.kind == "face":  # un-index: one colour per corner
            if len(vis.face_colors) != len(faces):  # never read past the colours (io.ply_colors matches PLYs)
                raise ValueError(f"{name!r} has {len(vis.face_colors):,} face colours for {len(faces):,} triangles")
            pos, colors, base = pos[faces].reshape(-1, 3), np.repeat(vis.face_colors, 3, axis=0), np.ones(4)
            faces = np.arange(len(pos)).reshape(-1, 3)
        elif vis.kind == "texture" and not is_placeholder(vis.material):  # the file's material, not trimesh's
            mat = vis.material
            if isinstance(mat, trimesh.visual.material.PBRMaterial):
                base, image = _color_factor(mat.baseColorFactor), mat.baseColorTexture
                if mat.alphaMode == "MASK":
                    cutoff = DEFAULT_ALPHA_CUTOFF if mat.alphaCutoff is None else float(mat.alphaCutoff)
                    if abs(base[3] - cutoff) <= 0.5 / 255:  # trimesh keeps the factor in bytes (0.3 -> 76/255):
                        base[3] = cutoff  # an alpha equal to the cutoff is drawn, as glTF says
            elif isinstance(mat, trimesh.visual.material.SimpleMaterial):
                base, image = _color_factor(mat.diffuse), mat.image
            if image is not None and vis.uv is not None and len(vis.uv) == len(pos):
                uv, wrap = vis.uv, getattr(mat, "sc3d_wrap", wrap)
            else:
                image = None  # a texture needs uv, and uv is read only for a texture
            colors = material_vertex_colors(vis, len(pos))
        pos = np.asarray(pos, dtype=np.float64)
        centre = (pos.min(axis=0) + pos.max(axis=0)) / 2
        shift = np.eye(4)
        shift[:3, 3] = centre
        yield MeshPart(model @ shift, np.ascontiguousarray(pos - centre, np.float32),
                       np.ascontiguousarray(faces, np.uint32), None if colors is None else np.ascontiguousarray(colors, np.uint8),
                       None if uv is None else np.ascontiguousarray(uv, np.float32), base, image, cutoff, wrap)


#: modes of texture images that PIL's ``Image.reduce`` refuses (palette, 1-bit)
UNREDUCIBLE_MODES = ("P", "PA", "1")


def eight_bit(image):
    """``image`` (a PIL texture) with 8 bits per channel. 16-bit grey PNGs open as mode
    ``I;16`` (``I`` in older Pillow), whose values run 0-65535; PIL's ``convert`` clips them at
    255, which would draw any such texture white, so they are scaled by 255/65535 here. Every
    other mode is returned as it is (16-bit RGB(A) PNGs already open as 8-bit ``RGB(A)``)."""
    if not (image.mode == "I" or image.mode.startswith("I;16")):
        return image
    from PIL import Image

    grey = np.clip(np.rint(np.asarray(image, dtype=np.float64) / 257.0), 0, 255).astype(np.uint8)
    return Image.fromarray(grey, "L")


class MeshRenderer:
    """Renders objects at the cameras of ``views`` with one persistent offscreen context.

    ``render(scene, to_canonical)`` takes a ``trimesh.Scene`` in its source frame and the
    4x4 source->canonical matrix and returns ``images [V,S,S,3] uint8``, ``masks [V,S,S]
    uint8`` (1 = object) and, when ``settings.depth``, ``depth [V,S,S] float32`` (camera-frame
    z in world units, 0 = background). Views are ordered as ``views.cameras()``; other
    cameras (same ``K``, ``V`` of them) can be passed as OpenCV ``R [V,3,3]``, ``t [V,3]``."""

    def __init__(self, views: ViewSettings, settings: RenderSettings = RenderSettings(),
                 backend: str = "egl"):
        activate(backend)
        from OpenGL import GL

        self.gl, self.views, self.settings, self.backend = GL, views, settings, backend
        self.cameras = views.cameras()
        self.S = S = views.image_size
        self.V = V = len(self.cameras["R"])
        self.cols = math.ceil(math.sqrt(V))
        self.rows = math.ceil(V / self.cols)
        self.znear, self.zfar = depth_range(views.distance)
        self.proj = gl_projection(self.cameras["K"][0], S, self.znear, self.zfar)
        self.views_gl = gl_view_matrices(self.cameras["R"], self.cameras["t"])
        self._platform = self._context(backend, S * self.cols, S * self.rows)
        self._pending: tuple[dict, bool] | None = None  # draw() submitted, read() not yet
        self._init_gl()

    @staticmethod
    def _context(backend: str, width: int, height: int):
        if backend == "egl":
            from pyrender.platforms import egl

            index = int(os.environ.get("EGL_DEVICE_ID", "0"))  # a worker's --gpus device (executors/devices.py)
            devices = egl.query_devices() if index else []
            if index and index >= len(devices):
                from sc3d_data.render.gl_backend import DeviceError

                raise DeviceError(f"EGL device {index} does not exist: this machine has {len(devices)} "
                                   f"(--gpus / EGL_DEVICE_ID take 0 to {max(len(devices) - 1, 0)})")
            platform = egl.EGLPlatform(width, height, device=egl.get_device_by_index(index))
        else:
            from pyrender.platforms.osmesa import OSMesaPlatform

            platform = OSMesaPlatform(width, height)
        platform.init_context()
        platform.make_current()
        return platform

    def _init_gl(self) -> None:
        GL = self.gl
        self.programs: dict[tuple[bool, bool], tuple[int, dict]] = {}
        self._views_now, self._views_serial = self.views_gl, 0  # the view matrices draws use
        self._views_of: dict[int, int] = {}  # program -> serial of the views it holds
        W, H = self.S * self.cols, self.S * self.rows
        self.fbo = GL.glGenFramebuffers(1)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        self.rbos = GL.glGenRenderbuffers(2)
        for rb, fmt, att in zip(self.rbos, (GL.GL_RGBA8, GL.GL_DEPTH_COMPONENT24),
                                (GL.GL_COLOR_ATTACHMENT0, GL.GL_DEPTH_ATTACHMENT)):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rb)
            GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, fmt, W, H)
            GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, att, GL.GL_RENDERBUFFER, rb)
        if GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RuntimeError("offscreen framebuffer is incomplete")
        GL.glViewport(0, 0, W, H)
        for i in range(4):
            GL.glEnable(GL.GL_CLIP_DISTANCE0 + i)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDisable(GL.GL_CULL_FACE)
        GL.glDisable(GL.GL_BLEND)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        bg = np.asarray(self.settings.background, dtype=np.float64) / 255.0
        GL.glClearColor(bg[0], bg[1], bg[2], 0.0)  # alpha 0 = background, 1 = object
        self.vao = GL.glGenVertexArrays(1)
        GL.glBindVertexArray(self.vao)
        # positions, colours, uv, indices of all parts of the object being drawn (_upload)
        self.buffers = list(GL.glGenBuffers(4))

    def _program(self, color: bool, texture: bool, cutoff: bool) -> dict:
        """Use (compile on first use) the program variant with the optional ``color`` and
        ``texture`` varyings and the alpha ``cutoff`` test (``_VARIANT_DEFINES``); its uniform
        locations, views up to date."""
        GL = self.gl
        key = (color, texture, cutoff)
        if key not in self.programs:
            from OpenGL.GL import shaders

            head = "#version 330 core\n" + "".join(
                _VARIANT_DEFINES[name] for name, on in (("color", color), ("texture", texture), ("cutoff", cutoff)) if on)
            program = shaders.compileProgram(
                shaders.compileShader(head + _VERTEX.replace("NVIEWS", str(self.V)), GL.GL_VERTEX_SHADER),
                shaders.compileShader(head + _FRAGMENT, GL.GL_FRAGMENT_SHADER), validate=False)
            GL.glUseProgram(program)
            loc = {n: GL.glGetUniformLocation(program, n) for n in
                   ("model", "view", "proj", "grid", "base_color", "base_texture", "ambient", "diffuse", "alpha_cutoff")}
            GL.glUniformMatrix4fv(loc["proj"], 1, GL.GL_TRUE, self.proj.astype(np.float32))
            GL.glUniform2f(loc["grid"], self.cols, self.rows)
            if texture:
                GL.glUniform1i(loc["base_texture"], 0)
            GL.glUniform1f(loc["ambient"], self.settings.ambient)
            GL.glUniform1f(loc["diffuse"], self.settings.light_intensity / math.pi)
            self.programs[key] = (program, loc)
        program, loc = self.programs[key]
        GL.glUseProgram(program)
        if self._views_of.get(program) != self._views_serial:
            GL.glUniformMatrix4fv(loc["view"], self.V, GL.GL_TRUE,
                                  np.ascontiguousarray(self._views_now, dtype=np.float32))
            self._views_of[program] = self._views_serial
        return loc

    def _use_views(self, views_gl: np.ndarray) -> None:
        """Draw with the world -> OpenGL camera matrices ``views_gl [V,4,4]`` from now on."""
        self._views_now, self._views_serial = views_gl, self._views_serial + 1

    def _texture(self, image, wrap: tuple[int, int]):
        GL = self.gl
        image = eight_bit(image)
        factor = math.ceil(max(image.size) / max(MAX_TEXTURE_SIZE, 8 * self.S))
        if factor > 1:  # box filter, as the first mipmap levels would be: saves memory and upload time
            # PIL's reduce refuses palette and 1-bit images (PNG optimisers' output, e.g. the 2048 px
            # texture of glTF's CesiumMilkTruck: "image has wrong mode"): those are converted first
            image = (image.convert("RGBA") if image.mode in UNREDUCIBLE_MODES else image).reduce(factor)
        # RGBA, not RGB: llvmpipe stores 4 bytes per texel either way, and converts RGB on upload
        # and in mipmap generation (5x / 1.6x slower); alpha is read only by cut-outs (alphaMode MASK)
        img = np.asarray(image.convert("RGBA"), dtype=np.uint8)[::-1]  # row 0 = v 0 (bottom)
        tex = GL.glGenTextures(1)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA8, img.shape[1], img.shape[0], 0, GL.GL_RGBA,
                        GL.GL_UNSIGNED_BYTE, np.ascontiguousarray(img))
        GL.glGenerateMipmap(GL.GL_TEXTURE_2D)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR_MIPMAP_LINEAR)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR)
        for p, mode in zip((GL.GL_TEXTURE_WRAP_S, GL.GL_TEXTURE_WRAP_T), wrap):
            GL.glTexParameteri(GL.GL_TEXTURE_2D, p, mode)
        if GL.GL_CLAMP_TO_BORDER in wrap:  # an MTL -clamp on: the material's colour (x 1) outside
            GL.glTexParameterfv(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_BORDER_COLOR, (1.0, 1.0, 1.0, 1.0))
        return tex

    def _upload(self, parts: list) -> list[tuple[int, int, int, int]]:
        """The vertex data of all ``parts`` (``mesh_parts``) into the renderer's four buffers, one
        upload each (the buffers' storage is re-specified per object: no buffer is made or deleted
        per part); per part the byte offsets of its positions, colours, uv and indices there."""
        GL = self.gl
        arrays: list[list[np.ndarray]] = [[], [], [], []]
        offsets, at = [], [0, 0, 0, 0]
        for part in parts:
            offsets.append(tuple(at))
            for k, data in enumerate((part.positions, part.colors, part.uv, part.faces)):
                if data is not None:
                    arrays[k].append(data)
                    at[k] += data.nbytes
        for k, target in enumerate((GL.GL_ARRAY_BUFFER,) * 3 + (GL.GL_ELEMENT_ARRAY_BUFFER,)):
            if arrays[k]:
                data = np.concatenate([a.reshape(-1) for a in arrays[k]])
                GL.glBindBuffer(target, self.buffers[k])
                GL.glBufferData(target, data.nbytes, data, GL.GL_STREAM_DRAW)
        return offsets

    def _draw_part(self, model, pos, faces, colors, uv, base, image, cutoff, wrap, offsets: tuple,
                   textures: dict) -> None:
        """Draw one part (``mesh_parts``) from its data at ``offsets`` in the buffers (``_upload``).
        ``textures`` maps ``(id(image), wrap)`` to ``(image, texture)`` for the textures this object has
        made so far: parts that share one image (a GLB's material used by many meshes) upload it once."""
        GL = self.gl
        has_tex = image is not None  # then uv too (mesh_parts)
        loc = self._program(colors is not None, has_tex, cutoff is not None)
        for attr, data, size, dtype, norm in ((0, pos, 3, GL.GL_FLOAT, False),
                                              (1, colors, 4, GL.GL_UNSIGNED_BYTE, True),
                                              (2, uv, 2, GL.GL_FLOAT, False)):
            if data is None:
                GL.glDisableVertexAttribArray(attr)
                continue
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.buffers[attr])
            GL.glVertexAttribPointer(attr, size, dtype, norm, 0, ctypes.c_void_p(offsets[attr]))
            GL.glEnableVertexAttribArray(attr)
        if has_tex:
            if (id(image), wrap) not in textures:  # the image is kept in the dict, so its id stays its own
                textures[id(image), wrap] = (image, self._texture(image, wrap))
            GL.glActiveTexture(GL.GL_TEXTURE0)
            GL.glBindTexture(GL.GL_TEXTURE_2D, textures[id(image), wrap][1])
        GL.glUniform4f(loc["base_color"], *[float(x) for x in base])
        if cutoff is not None:
            GL.glUniform1f(loc["alpha_cutoff"], cutoff)
        GL.glUniformMatrix4fv(loc["model"], 1, GL.GL_TRUE, model.astype(np.float32))
        GL.glDrawElementsInstanced(GL.GL_TRIANGLES, faces.size, GL.GL_UNSIGNED_INT, ctypes.c_void_p(offsets[3]),
                                   self.V)

    def _tiles(self, atlas: np.ndarray) -> np.ndarray:
        """``[rows*S, cols*S, ...]`` (OpenGL rows: bottom first) -> ``[V, S, S, ...]`` (top first)."""
        S, c, r = self.S, self.cols, self.rows
        a = atlas[::-1].reshape(r, S, c, S, *atlas.shape[2:]).swapaxes(1, 2)
        return a.reshape(r * c, S, S, *atlas.shape[2:])[:self.V]

    def render(self, scene, to_canonical: np.ndarray, R: np.ndarray | None = None,
               t: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Render all views of one object (see class doc for shapes): :meth:`draw`, then :meth:`read`."""
        self.draw(scene, to_canonical, R, t)
        return self.read()

    def draw(self, scene, to_canonical: np.ndarray, R: np.ndarray | None = None,
             t: np.ndarray | None = None) -> None:
        """Submit all draws of one object (cameras as :meth:`render`) and flush them, without
        waiting: a GPU draws while the caller goes on (e.g. voxelizes the object), and
        :meth:`read` finds the pixels ready instead of waiting for them in ``glReadPixels``.
        A ``draw`` not yet read is dropped by the next ``draw``."""
        GL = self.gl
        if self._pending is not None:  # an object interrupted between draw and read: drop it
            self._release_pending()
        self._platform.make_current()
        if R is not None:
            if len(R) != self.V:
                raise ValueError(f"expected {self.V} cameras, got {len(R)}")
            self._use_views(gl_view_matrices(np.asarray(R, np.float64), np.asarray(t, np.float64)))
        self._pending = ({}, R is not None)  # textures, cameras to put back
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        try:
            parts = list(mesh_parts(scene, to_canonical))
            for part, offsets in zip(parts, self._upload(parts)):
                self._draw_part(*part, offsets, self._pending[0])
            GL.glFlush()
        except BaseException:
            self._release_pending()
            raise

    def read(self) -> dict[str, np.ndarray]:
        """The images and masks (and depth) of the object of the last :meth:`draw` (class doc)."""
        GL = self.gl
        if self._pending is None:
            raise RuntimeError("MeshRenderer.read called without draw")
        try:
            W, H = self.S * self.cols, self.S * self.rows
            rgba = np.frombuffer(GL.glReadPixels(0, 0, W, H, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE),
                                 dtype=np.uint8).reshape(H, W, 4)
            tiles = self._tiles(rgba)
            out = {"images": np.ascontiguousarray(tiles[..., :3]),
                   "masks": (tiles[..., 3] > 0).astype(np.uint8)}
            if self.settings.depth:
                d = np.frombuffer(GL.glReadPixels(0, 0, W, H, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT),
                                  dtype=np.float32).reshape(H, W)
                d = self._tiles(d)
                n, f = self.znear, self.zfar
                z = (2.0 * n * f / ((f + n) - (2.0 * d.astype(np.float64) - 1.0) * (f - n)))
                out["depth"] = np.where(out["masks"] > 0, z, 0.0).astype(np.float32)
        finally:
            self._release_pending()
        return out

    def _release_pending(self) -> None:
        """Delete the textures of the last :meth:`draw`; its cameras back to the default."""
        GL = self.gl
        textures, own_cameras = self._pending
        self._pending = None
        if textures:
            GL.glDeleteTextures([tex for _, tex in textures.values()])
        if own_cameras:
            self._use_views(self.views_gl)

    def close(self) -> None:
        """Free the GL context; the renderer cannot be used afterwards. With EGL the context is
        first released from this thread and the thread's EGL state after the display is
        terminated (EGL's own teardown order: pyrender destroys a context that is still current,
        which some drivers, NVIDIA's among them, trip over when the process exits)."""
        platform, self._platform = self._platform, None
        if platform is None:
            return
        if self.backend != "egl":
            platform.delete_context()
            return
        from OpenGL import EGL

        display = getattr(platform, "_egl_display", None)
        if display is not None:
            EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        platform.delete_context()
        EGL.eglReleaseThread()
