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

"""The lit pass of ``MeshRenderer.render_lit`` in one GL context (see ``scene_light``)."""

from collections.abc import Sequence

import moderngl
import numpy as np

from bbpose_ros.core.render import lit_shaders
from bbpose_ros.core.render.clip_space import gl_matrix
from bbpose_ros.core.render.scene_light import light_matrix, MAX_LIGHTS, PointLight, \
    SceneLights, SHADOW_MAP_SIZE, TexturedPlane
from bbpose_ros.core.util.errors import InputError

# Depth offset of the shadow pass (glPolygonOffset factor, units): no self-shadow acne.
_SHADOW_OFFSET = (2.0, 8.0)


class LitPass:
    """The programs, shadow maps and plane buffers of the lit pass in one GL context."""

    def __init__(self, ctx: moderngl.Context,
                 buffers: dict[str, tuple[moderngl.Buffer, moderngl.Buffer]],
                 frame: moderngl.Framebuffer) -> None:
        self.ctx, self.frame = ctx, frame
        self.lit = ctx.program(vertex_shader=lit_shaders.LIT_VERTEX,
                               fragment_shader=lit_shaders.LIT_FRAGMENT)
        self.shadow = ctx.program(vertex_shader=lit_shaders.SHADOW_VERTEX,
                                  fragment_shader=lit_shaders.SHADOW_FRAGMENT)
        self.vaos = {
            name: (ctx.vertex_array(self.lit, [(vbo, '3f 3f 3f', 'in_position', 'in_normal',
                                                'in_color')], ibo, index_element_size=4),
                   ctx.vertex_array(self.shadow, [(vbo, '3f 24x', 'in_position')], ibo,
                                    index_element_size=4))
            for name, (vbo, ibo) in buffers.items()}
        # The unit square z = 0, |x|, |y| <= 1: position, normal, white colour, uv.
        square = np.array([[x, y, 0, 0, 0, 1, 1, 1, 1, x, y]
                           for x, y in ((-1, -1), (1, -1), (1, 1), (-1, 1))], dtype='f4')
        self.square = ctx.vertex_array(
            self.lit, [(ctx.buffer(square.tobytes()), '3f 3f 3f 2f', 'in_position',
                        'in_normal', 'in_color', 'in_uv')],
            ctx.buffer(np.array([0, 1, 2, 0, 2, 3], 'u4').tobytes()), index_element_size=4)
        self.maps = []
        for _ in range(MAX_LIGHTS):
            depth = ctx.depth_texture((SHADOW_MAP_SIZE,) * 2)
            depth.compare_func = '<='
            depth.filter = (moderngl.LINEAR, moderngl.LINEAR)
            depth.repeat_x = depth.repeat_y = False
            self.maps.append((depth, ctx.framebuffer(depth_attachment=depth)))
        self.textures = {}
        self.rgba = np.empty((frame.height, frame.width, 4), np.uint8)
        self.ids = np.empty((frame.height, frame.width), np.uint8)

    def render(self, draws, materials, lights: SceneLights, planes: Sequence[TexturedPlane],
               projection: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the lit RGBA (H, W, 4) (alpha 255 where drawn) and ids (H, W), fresh."""
        if len(lights.lights) > MAX_LIGHTS:
            raise InputError(f'at most {MAX_LIGHTS} lights, got {len(lights.lights)}')
        ctx, program = self.ctx, self.lit
        matrices = [light_matrix(light, lights.shadow_center, lights.shadow_radius)
                    for light in lights.lights]
        textures = [self._texture(slot, plane.texture) for slot, plane in enumerate(planes)]
        self._shadow_maps(draws if lights.cast_shadows else (), matrices)
        self.frame.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        self.frame.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        program['u_projection'].write(gl_matrix(projection))
        program['u_light_count'].value = len(lights.lights)
        padded = list(lights.lights) + [PointLight((0.0, 0.0, 0.0))] * \
            (MAX_LIGHTS - len(lights.lights))
        program['u_light_position'].write(np.array([p.position for p in padded], 'f4'))
        program['u_light_color'].write(np.array([p.color for p in padded], 'f4'))
        program['u_light_matrix'].write(b''.join(
            gl_matrix(m) for m in matrices + [np.eye(4)] * (MAX_LIGHTS - len(matrices))))
        for index, (depth, _) in enumerate(self.maps):
            depth.use(location=index + 1)
            program[f'u_shadow{index}'].value = index + 1
        program['u_shadow_texel'].value = 1.0 / SHADOW_MAP_SIZE
        program['u_ambient'].value = tuple(float(x) for x in lights.ambient)
        program['u_texture'].value = 0
        program['u_textured'].value = False
        program['u_uv_scale'].value = (1.0, 1.0)
        for index, (draw, material) in enumerate(zip(draws, materials)):
            self._set_pose(program, draw.rotation, draw.translation)
            self._set_material(program, draw.color_gain, material, index + 1)
            self.vaos[draw.mesh][0].render()
        program['u_textured'].value = True
        for plane, texture in zip(planes, textures):
            half = np.asarray(plane.half_size, dtype=float)
            self._set_pose(program, np.asarray(plane.rotation) @ np.diag([*half, 1.0]),
                           plane.translation)
            self._set_material(program, (1.0, 1.0, 1.0), plane.material, 0)
            program['u_uv_scale'].value = tuple(float(h / plane.tile) for h in half)
            texture.use(location=0)
            self.square.render()
        self.frame.read_into(self.rgba, components=4, attachment=0, alignment=1)
        self.frame.read_into(self.ids, components=1, attachment=1, alignment=1)
        return self.rgba.copy(), self.ids.copy()

    def _shadow_maps(self, draws, matrices):
        """Render each light's depth image of the meshes (none: nothing in shadow)."""
        ctx, program = self.ctx, self.shadow
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.polygon_offset = _SHADOW_OFFSET
        try:
            for matrix, (_, fbo) in zip(matrices, self.maps):
                fbo.use()
                fbo.clear(depth=1.0)
                program['u_light_matrix'].write(gl_matrix(matrix))
                for draw in draws:
                    self._set_pose(program, draw.rotation, draw.translation)
                    self.vaos[draw.mesh][1].render()
        finally:
            ctx.polygon_offset = (0.0, 0.0)

    @staticmethod
    def _set_pose(program, rotation, translation):
        program['u_rotation'].write(gl_matrix(rotation))
        program['u_translation'].value = tuple(float(x) for x in translation)

    @staticmethod
    def _set_material(program, color_gain, material, instance_id):
        program['u_color_gain'].value = tuple(float(x) for x in color_gain)
        program['u_specular'].value = float(material.specular)
        program['u_shininess'].value = float(material.shininess)
        program['u_instance_id'].value = float(instance_id)

    def _texture(self, slot, image):
        """
        Return the GL texture of plane ``slot``, holding an (T, T2, 3) uint8 image.

        Uploaded before anything is drawn: an upload in the middle of a frame makes
        llvmpipe rasterise what was drawn so far.
        """
        image = np.ascontiguousarray(image, dtype=np.uint8)
        if image.ndim != 3 or image.shape[2] != 3:
            raise InputError(f'plane texture must be (T, T2, 3) uint8, got {image.shape}')
        size = (image.shape[1], image.shape[0])
        texture = self.textures.get(slot)
        if texture is None or texture.size != size:
            if texture is not None:
                texture.release()
            texture = self.textures[slot] = self.ctx.texture(size, 3)
            texture.repeat_x = texture.repeat_y = True
        texture.write(image.tobytes())
        texture.build_mipmaps()
        return texture
