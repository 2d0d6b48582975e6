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
GLSL 3.30 shaders of ``MeshRenderer``.

Positions are model coordinates in metres, moved to the OpenCV camera frame by the uniforms
``u_rotation`` (model to camera) and ``u_translation`` (metres), then projected by
``u_projection`` (see ``opengl_projection``).
"""

SHADED_VERTEX = """
#version 330
uniform mat4 u_projection;
uniform mat3 u_rotation;
uniform vec3 u_translation;
in vec3 in_position;
in vec3 in_normal;
in vec3 in_color;
out vec3 v_position;
out vec3 v_normal;
out vec3 v_color;
out vec3 v_model;
void main() {
    v_model = in_position;
    v_position = u_rotation * in_position + u_translation;
    v_normal = u_rotation * in_normal;
    v_color = in_color;
    gl_Position = u_projection * vec4(v_position, 1.0);
}
"""

# Lambert shading of the interpolated vertex colour; the normal is turned towards the camera
# so that back faces seen through holes are lit like front faces. Output 1 is the instance
# id as a normalised 8-bit value (id / 255); output 2 the model coordinates (metres) of the
# surface point, interpolated perspective-correctly (the dense correspondences' target).
SHADED_FRAGMENT = """
#version 330
uniform vec3 u_light_direction;
uniform float u_ambient;
uniform float u_diffuse;
uniform vec3 u_color_gain;
uniform float u_instance_id;
in vec3 v_position;
in vec3 v_normal;
in vec3 v_color;
in vec3 v_model;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_id;
layout(location = 2) out vec4 f_model;
void main() {
    vec3 normal = normalize(v_normal);
    if (dot(normal, v_position) > 0.0) {
        normal = -normal;
    }
    float shade = u_ambient + u_diffuse * max(dot(normal, u_light_direction), 0.0);
    f_color = vec4(clamp(v_color * u_color_gain * shade, 0.0, 1.0), 1.0);
    f_id = u_instance_id / 255.0;
    f_model = vec4(v_model, 1.0);
}
"""

SILHOUETTE_VERTEX = """
#version 330
uniform mat4 u_projection;
uniform mat3 u_rotation;
uniform vec3 u_translation;
in vec3 in_position;
void main() {
    gl_Position = u_projection * vec4(u_rotation * in_position + u_translation, 1.0);
}
"""

SILHOUETTE_FRAGMENT = """
#version 330
out float f_mask;
void main() {
    f_mask = 1.0;
}
"""
