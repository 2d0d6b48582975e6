# Copyright 2026 bbpose_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Headless OpenGL renderer of coloured meshes (moderngl, standalone EGL context).

On a machine without a GPU, EGL runs on Mesa's llvmpipe (CPU); it needs the system
libraries ``libegl1`` and ``libgl1``. The GL context is created lazily, on the first
``render`` call of each process, so a renderer may be handed to worker processes. After a
process has made a GL context, children it forks hang on their first rendering: such
children get a RuntimeError instead. Start workers with the 'spawn' or 'forkserver'
method, or fork them before the parent renders.
"""

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
import math
import os
from typing import Any

import moderngl
import numpy as np

from bbpose_ros.core.geometry.camera import CameraIntrinsics
from bbpose_ros.core.geometry.projection import projected_box_uv
from bbpose_ros.core.render import shaders
from bbpose_ros.core.render.clip_space import gl_matrix, opengl_projection
from bbpose_ros.core.render.mesh import RenderMesh
from bbpose_ros.core.render.scene_light import Material, SceneLights, TexturedPlane
from bbpose_ros.core.util.errors import InputError

# The instance-id target is 8 bits wide and 0 is the background.
MAX_DRAWS = 255
# Id of the process that made the first GL context of this interpreter (see the module doc).
_context_pid = None


@dataclass(frozen=True)
class Draw:
    """
    One mesh instance to draw.

    Attributes:
        mesh: key of the mesh in the renderer's ``meshes``.
        rotation: (3, 3) model-to-camera rotation.
        translation: (3,) model origin in the camera frame, metres.
        color_gain: (3,) RGB factors applied to the mesh's colours before shading.

    """

    mesh: str
    rotation: np.ndarray
    translation: np.ndarray
    color_gain: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Lighting:
    """
    One directional light plus ambient light; shade = ambient + diffuse * max(n . l, 0).

    Attributes:
        direction: (3,) unit vector from the surface towards the light, camera frame
            (x right, y down, z forward; a light behind the camera has direction z < 0).
        ambient: ambient intensity (colour factor).
        diffuse: intensity of the directional light.

    """

    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    ambient: float = 0.4
    diffuse: float = 0.6


@dataclass(frozen=True)
class RenderResult:
    """
    What one ``MeshRenderer.render`` call produced (fresh arrays, owned by the caller).

    Attributes:
        rgb: (H, W, 3) uint8 shaded objects on a black background.
        instance_ids: (H, W) uint8; i + 1 where draw i is the front-most surface, 0 where no
            mesh covers the pixel centre.
        full_masks: {draw index: (H, W) bool} silhouette of the draw alone (unoccluded),
            inside the image.
        full_pixel_counts: {draw index: int} pixel count of that whole silhouette, parts
            outside the image included (the denominator of BOP's visib_fract).
        model_coordinates: (H, W, 3) float32 model coordinates (metres, the front-most
            draw's own model frame) of the surface point seen at each pixel centre, 0 where
            no mesh covers it; None unless asked for (``render(..., coordinates=True)``).

    """

    rgb: np.ndarray
    instance_ids: np.ndarray
    full_masks: dict[int, np.ndarray]
    full_pixel_counts: dict[int, int]
    model_coordinates: np.ndarray | None = None


@dataclass(frozen=True, kw_only=True)
class LitRenderResult(RenderResult):
    """
    What ``MeshRenderer.render_lit`` produced: a ``RenderResult`` plus the drawn pixels.

    Attributes:
        covered: (H, W) bool pixels a mesh or a plane covers (the rest is empty).

    """

    covered: np.ndarray


class MeshRenderer:
    """
    Render coloured meshes with a shared depth buffer, instance ids and full silhouettes.

    ``camera`` is the ``CameraIntrinsics`` of every image; ``meshes`` maps names to
    ``RenderMesh``. ``near`` and ``far`` (metres) bound the depth range. A pixel belongs to
    a mesh when its centre (OpenCV convention) is inside a projected triangle; there is no
    anti-aliasing. Not thread-safe: use one renderer per thread. Several renderers may take
    turns in one process: each makes its own context current before drawing.
    """

    def __init__(self, camera: CameraIntrinsics, meshes: Mapping[str, RenderMesh],
                 near: float = 0.01, far: float = 20.0) -> None:
        if not 0.0 < near < far:
            raise InputError(f'invalid depth range near={near}, far={far} (metres)')
        self.camera = camera
        self.meshes = dict(meshes)
        self.near = near
        self.far = far
        self._gl = None
        self._pid = None

    def __getstate__(self) -> dict[str, Any]:
        """Pickle without the GL state; the receiving process creates its own context."""
        state = self.__dict__.copy()
        state['_gl'] = None
        state['_pid'] = None
        return state

    def close(self) -> None:
        """Release the GL context of this process (a later ``render`` makes a new one)."""
        if self._gl is not None and self._pid == os.getpid():
            self._gl.release()
        self._gl = None
        self._pid = None

    def render(self, draws: Sequence[Draw], lighting: Lighting,
               full_mask_indices: Iterable[int] = (),
               camera: CameraIntrinsics | None = None,
               coordinates: bool = False) -> RenderResult:
        """
        Draw ``draws`` (a sequence of ``Draw``) in one image under ``lighting``.

        ``full_mask_indices`` lists the draws whose full (unoccluded) silhouette is wanted.
        Every draw must lie in front of the camera. ``camera`` replaces the renderer's
        intrinsics for this image (same width and height), e.g. to render a crop of a larger
        frame (``CameraIntrinsics.cropped``). ``coordinates`` also reads back the model
        coordinates of every pixel. Returns a ``RenderResult``.
        """
        camera = self._checked_camera(draws, camera)
        gl = self._context()
        rgb, ids, model_coordinates = gl.render_shaded(draws, lighting, camera, coordinates)
        return RenderResult(rgb, ids, *self._full_masks(gl, draws, ids, full_mask_indices,
                                                        camera), model_coordinates)

    def render_lit(self, draws: Sequence[Draw], lights: SceneLights,
                   materials: Sequence[Material] | None = None,
                   planes: Sequence[TexturedPlane] = (),
                   full_mask_indices: Iterable[int] = (),
                   camera: CameraIntrinsics | None = None) -> LitRenderResult:
        """
        Draw ``draws`` and textured ``planes`` under point lights with shadows and highlights.

        Like ``render`` (same instance ids, full masks and ``camera``), but lit by a
        ``SceneLights`` (ambient, up to three shadow-casting point lights, Blinn-Phong
        highlights with each draw's ``Material``; default matte) and with the planes (a
        table, walls: id 0) in the depth buffer. Returns a ``LitRenderResult``.
        """
        from bbpose_ros.core.render.lit_pass import LitPass
        camera = self._checked_camera(draws, camera)
        materials = [Material()] * len(draws) if materials is None else list(materials)
        if len(materials) != len(draws):
            raise InputError(f'{len(materials)} materials for {len(draws)} draws')
        gl = self._context()
        if gl.lit_pass is None:
            gl.lit_pass = LitPass(gl.ctx, gl.buffers, gl.frame)
        rgba, ids = gl.lit_pass.render(draws, materials, lights, planes, opengl_projection(
            camera, self.near, self.far))
        return LitRenderResult(np.ascontiguousarray(rgba[..., :3]), ids,
                               *self._full_masks(gl, draws, ids, full_mask_indices, camera),
                               covered=rgba[..., 3] > 0)

    def _checked_camera(self, draws, camera):
        """Return the camera of one image (default the renderer's), checked with the draws."""
        camera = self.camera if camera is None else camera
        if (camera.width, camera.height) != (self.camera.width, self.camera.height):
            raise InputError(f'render camera is {camera.width}x{camera.height}, the renderer '
                             f'was made for {self.camera.width}x{self.camera.height}')
        if len(draws) > MAX_DRAWS:
            raise InputError(f'at most {MAX_DRAWS} meshes per image, got {len(draws)}')
        unknown = sorted({draw.mesh for draw in draws} - set(self.meshes))
        if unknown:
            raise InputError(f'unknown mesh name(s): {", ".join(unknown)}')
        return camera

    def _full_masks(self, gl, draws, ids, full_mask_indices, camera):
        """Full silhouettes {index: (H, W) bool} and pixel counts of the chosen draws."""
        boxes = [projected_box_uv(camera, self.meshes[draw.mesh].hull_points,
                                  draw.rotation, draw.translation) for draw in draws]
        full_masks, counts = {}, {}
        for index in full_mask_indices:
            if self._is_unoccluded_and_inside(index, boxes):
                full_masks[index] = ids == index + 1
                counts[index] = int(np.count_nonzero(full_masks[index]))
            else:
                full_masks[index], counts[index] = gl.render_silhouette(
                    draws[index], boxes[index], camera)
        return full_masks, counts

    def _is_unoccluded_and_inside(self, index, boxes):
        """Tell whether no other draw's box overlaps draw ``index``'s box, inside the image."""
        u0, v0, u1, v1 = boxes[index]
        if u0 < -0.5 or v0 < -0.5 or u1 > self.camera.width - 0.5 or \
                v1 > self.camera.height - 0.5:
            return False
        return not any(other != index and box[0] < u1 and u0 < box[2] and box[1] < v1 and
                       v0 < box[3] for other, box in enumerate(boxes))

    def _context(self):
        global _context_pid
        if self._gl is None or self._pid != os.getpid():
            if _context_pid not in (None, os.getpid()):
                raise RuntimeError(
                    f'this process was forked from process {_context_pid} after it had made '
                    'an OpenGL context; EGL would hang here. Start worker processes with the '
                    '"spawn" or "forkserver" method (DataLoader multiprocessing_context), or '
                    'before the parent renders.')
            self._gl = _GlState(self.camera, self.meshes, self.near, self.far)
            self._pid = _context_pid = os.getpid()
        # Another renderer of this process may have made its own context current since.
        self._gl.ctx.__enter__()
        return self._gl


class _GlState:
    """The moderngl context, programs, mesh buffers and framebuffers of one process."""

    def __init__(self, camera, meshes, near, far):
        try:
            self.ctx = moderngl.create_standalone_context(backend='egl')
        except Exception as err:  # moderngl raises bare Exception for missing libraries
            raise RuntimeError(
                f'cannot create a headless OpenGL (EGL) context: {err}. Install the system '
                'packages libegl1 and libgl1 (Mesa llvmpipe renders on the CPU).') from err
        self.near, self.far = near, far
        ctx = self.ctx
        self.shaded = ctx.program(vertex_shader=shaders.SHADED_VERTEX,
                                  fragment_shader=shaders.SHADED_FRAGMENT)
        self.silhouette = ctx.program(vertex_shader=shaders.SILHOUETTE_VERTEX,
                                      fragment_shader=shaders.SILHOUETTE_FRAGMENT)
        self.vaos, self.buffers = {}, {}
        # The lit pass (``render_lit``) is made on first use.
        self.lit_pass = None
        for name, mesh in meshes.items():
            vbo = ctx.buffer(np.hstack([mesh.vertices, mesh.normals, mesh.colors])
                             .astype('f4').tobytes())
            ibo = ctx.buffer(mesh.faces.astype('u4').tobytes())
            self.buffers[name] = (vbo, ibo)
            self.vaos[name] = (
                ctx.vertex_array(self.shaded, [(vbo, '3f 3f 3f', 'in_position', 'in_normal',
                                                'in_color')], ibo, index_element_size=4),
                ctx.vertex_array(self.silhouette, [(vbo, '3f 24x', 'in_position')], ibo,
                                 index_element_size=4))
        size = (camera.width, camera.height)
        self.frame = ctx.framebuffer(
            color_attachments=[ctx.renderbuffer(size, 4), ctx.renderbuffer(size, 1),
                               ctx.renderbuffer(size, 4, dtype='f4')],
            depth_attachment=ctx.depth_renderbuffer(size))
        # The silhouette window may be larger than the image: objects leave the frame.
        self.window_size = (2 * camera.width, 2 * camera.height)
        self.window = ctx.framebuffer(color_attachments=[ctx.renderbuffer(self.window_size, 1)])
        self.rgb = np.empty((camera.height, camera.width, 3), np.uint8)
        self.ids = np.empty((camera.height, camera.width), np.uint8)
        self.model = np.empty((camera.height, camera.width, 3), np.float32)
        self.window_pixels = np.empty(self.window_size[0] * self.window_size[1], np.uint8)

    def release(self):
        """Free the context and everything made in it."""
        self.ctx.release()

    def render_shaded(self, draws, lighting, camera, coordinates):
        """
        Draw all draws; return fresh arrays of their colours, ids and coordinates.

        Shaded colours (H, W, 3), instance ids (H, W) and, with ``coordinates``, model
        coordinates (H, W, 3) float32 (else None).
        """
        ctx, program = self.ctx, self.shaded
        program['u_projection'].write(gl_matrix(opengl_projection(camera, self.near,
                                                                  self.far)))
        self.frame.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        self.frame.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        direction = np.asarray(lighting.direction, dtype=float)
        program['u_light_direction'].value = tuple(direction / np.linalg.norm(direction))
        program['u_ambient'].value = float(lighting.ambient)
        program['u_diffuse'].value = float(lighting.diffuse)
        for index, draw in enumerate(draws):
            program['u_rotation'].write(gl_matrix(draw.rotation))
            program['u_translation'].value = tuple(float(x) for x in draw.translation)
            program['u_color_gain'].value = tuple(float(x) for x in draw.color_gain)
            program['u_instance_id'].value = float(index + 1)
            self.vaos[draw.mesh][0].render()
        self.frame.read_into(self.rgb, components=3, attachment=0, alignment=1)
        self.frame.read_into(self.ids, components=1, attachment=1, alignment=1)
        model = None
        if coordinates:
            self.frame.read_into(self.model, components=3, attachment=2, alignment=1,
                                 dtype='f4')
            model = self.model.copy()
        return self.rgb.copy(), self.ids.copy(), model

    def render_silhouette(self, draw, box_uv, camera):
        """
        Render the unoccluded silhouette of one draw whose amodal box is ``box_uv``.

        Rendered in a window around the box, so parts outside the image count too. Returns
        the (H, W) bool mask inside the image and the whole silhouette's pixel count.
        """
        # Pixels whose centres can be inside the box, one pixel of margin each side.
        col0, row0 = math.ceil(box_uv[0]) - 1, math.ceil(box_uv[1]) - 1
        width = min(math.floor(box_uv[2]) + 2 - col0, self.window_size[0])
        height = min(math.floor(box_uv[3]) + 2 - row0, self.window_size[1])
        program = self.silhouette
        program['u_projection'].write(gl_matrix(opengl_projection(
            camera, self.near, self.far, (col0, row0), (width, height))))
        program['u_rotation'].write(gl_matrix(draw.rotation))
        program['u_translation'].value = tuple(float(x) for x in draw.translation)
        self.window.use()
        self.window.viewport = (0, 0, width, height)
        self.ctx.disable(moderngl.DEPTH_TEST)
        self.window.clear(0.0, viewport=(0, 0, width, height))
        self.vaos[draw.mesh][1].render()
        pixels = self.window_pixels[:width * height]
        self.window.read_into(pixels, viewport=(0, 0, width, height), components=1,
                              alignment=1)
        local = pixels.reshape(height, width) > 0
        mask = np.zeros((camera.height, camera.width), bool)
        c0, r0 = max(col0, 0), max(row0, 0)
        c1, r1 = min(col0 + width, camera.width), min(row0 + height, camera.height)
        if c0 < c1 and r0 < r1:
            mask[r0:r1, c0:c1] = local[r0 - row0:r1 - row0, c0 - col0:c1 - col0]
        return mask, int(np.count_nonzero(local))
