"""One reusable offscreen renderer per process: RGB, silhouette masks and depth of an object
seen from the cameras of ``sc3d_data.camera.ViewSettings``.

The renderer and its pyrender scene (camera, headlight, ambient light) are created once;
per object only the mesh node is swapped and per view only the camera (and the headlight that
follows it) moves (NOTES-rendering.md: a renderer per mesh is 2-5x slower). Multisampling is
OFF, so every coloured pixel is a pixel with depth > 0: the mask (depth > 0) and the RGB agree
exactly (with pyrender's default 4x MSAA about 8% of silhouette pixels disagree). Back-face
culling is off (most real meshes have inconsistent winding).

Cameras: the shards store OpenCV ``K, R, t`` (world->camera, x right, y down, z forward);
``opengl_camera_pose`` converts them into pyrender's camera-to-world pose with OpenGL axes
(x right, y up, z backward). This conversion lives here and nowhere else.

Call ``sc3d_data.gl_backend.activate(backend)`` (done by ``MeshRenderer``) before anything
imports pyrender, and never fork a process after a renderer exists.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sc3d_data.camera import ViewSettings
from sc3d_data.gl_backend import activate

#: OpenCV camera axes -> OpenGL camera axes (flip y and z)
_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def opengl_camera_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """pyrender camera pose [4,4] (camera->world, OpenGL axes) from OpenCV world->camera
    ``R [3,3]``, ``t [3]``."""
    pose = np.eye(4)
    pose[:3, :3] = R.T
    pose[:3, 3] = -R.T @ t
    return pose @ _CV_TO_GL


def _patch_msaa(samples: int) -> None:
    """Make pyrender's offscreen framebuffer use ``samples`` MSAA samples (0 = off; pyrender
    hard-codes 4). Affects every pyrender renderer in this process."""
    import pyrender.renderer as prr

    original = getattr(prr, "_sc3d_original_storage_ms", prr.glRenderbufferStorageMultisample)
    prr._sc3d_original_storage_ms = original

    def storage(target, _samples, fmt, width, height):
        return original(target, samples, fmt, width, height)

    prr.glRenderbufferStorageMultisample = storage


@dataclass(frozen=True)
class RenderSettings:
    """How objects look: ``background`` RGB 0-255, ``depth`` (also return depth maps),
    ``light_intensity`` of the headlight (a directional light at the camera), ``ambient``
    light level (0-1), ``msaa`` samples (0 keeps masks and RGB in exact agreement)."""

    background: tuple[int, int, int] = (255, 255, 255)
    depth: bool = False
    light_intensity: float = 1.5
    ambient: float = 0.2
    msaa: int = 0


class MeshRenderer:
    """Renders objects at the cameras of ``views`` with one persistent offscreen renderer.

    ``render(scene, to_canonical)`` takes a ``trimesh.Scene`` in its source frame and the
    4x4 source->canonical matrix and returns ``images [V,S,S,3] uint8``, ``masks [V,S,S]
    uint8`` (1 = object) and, when ``settings.depth``, ``depth [V,S,S] float32`` (camera-frame
    z in world units, 0 = background). Views are ordered as ``views.cameras()``."""

    def __init__(self, views: ViewSettings, settings: RenderSettings = RenderSettings(),
                 backend: str = "egl"):
        activate(backend)
        import pyrender

        _patch_msaa(settings.msaa)
        self._pyrender = pyrender
        self.views, self.settings, self.backend = views, settings, backend
        self.cameras = views.cameras()
        S = views.image_size
        K = self.cameras["K"][0]
        bg = np.array(list(settings.background) + [255], dtype=np.float64) / 255.0
        self.scene = pyrender.Scene(bg_color=bg, ambient_light=np.full(3, settings.ambient))
        far = views.distance + 10.0
        camera = pyrender.IntrinsicsCamera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2],
                                           znear=0.01, zfar=far)
        self.camera_node = self.scene.add(camera)
        self.light_node = self.scene.add(pyrender.DirectionalLight(color=np.ones(3),
                                                                   intensity=settings.light_intensity))
        self.poses = [opengl_camera_pose(R, t) for R, t in zip(self.cameras["R"], self.cameras["t"])]
        self.renderer = pyrender.OffscreenRenderer(S, S)
        self.flags = pyrender.RenderFlags.SKIP_CULL_FACES
        self._object_node = None

    def _set_object(self, scene, to_canonical: np.ndarray) -> None:
        import trimesh

        pyrender = self._pyrender
        if self._object_node is not None:
            self.scene.remove_node(self._object_node)
        root = pyrender.Node(matrix=np.asarray(to_canonical, dtype=np.float64))
        self.scene.add_node(root)
        for node in scene.graph.nodes_geometry:
            transform, name = scene.graph[node]
            geom = scene.geometry[name]
            if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
                continue
            mesh = pyrender.Mesh.from_trimesh(geom)
            self.scene.add(mesh, pose=transform, parent_node=root)
        self._object_node = root

    def render(self, scene, to_canonical: np.ndarray) -> dict[str, np.ndarray]:
        """Render all views of one object (see class doc for shapes)."""
        self._set_object(scene, to_canonical)
        V, S = len(self.poses), self.views.image_size
        images = np.empty((V, S, S, 3), dtype=np.uint8)
        masks = np.empty((V, S, S), dtype=np.uint8)
        depth = np.empty((V, S, S), dtype=np.float32) if self.settings.depth else None
        bg = np.array(self.settings.background, dtype=np.uint8)
        for v, pose in enumerate(self.poses):
            self.scene.set_pose(self.camera_node, pose)
            self.scene.set_pose(self.light_node, pose)
            color, d = self.renderer.render(self.scene, flags=self.flags)
            m = d > 0
            images[v] = color
            images[v][~m] = bg  # exact background where there is no object
            masks[v] = m
            if depth is not None:
                depth[v] = d
        out = {"images": images, "masks": masks}
        if depth is not None:
            out["depth"] = depth
        return out

    def close(self) -> None:
        """Free the GL context (``delete``); the renderer cannot be used afterwards."""
        if self.renderer is not None:
            self.renderer.delete()
            self.renderer = None
