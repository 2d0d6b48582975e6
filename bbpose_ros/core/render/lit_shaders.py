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
GLSL 3.30 shaders of ``MeshRenderer.render_lit``: Blinn-Phong light with shadow maps.

Positions are model coordinates in metres, moved to the OpenCV camera frame by
``u_rotation`` (model to camera; for a plane it also scales its unit square) and
``u_translation`` (metres), then projected by ``u_projection``. Each light has a shadow map
rendered from its position by ``SHADOW_VERTEX``; ``u_light_matrix[i]`` maps camera-frame
points to that light's clip space.
"""

MAX_LIGHTS = 3

LIT_VERTEX = """
#version 330
uniform mat4 u_projection;
uniform mat3 u_rotation;
uniform vec3 u_translation;
uniform vec2 u_uv_scale;
in vec3 in_position;
in vec3 in_normal;
in vec3 in_color;
in vec2 in_uv;
out vec3 v_position;
out vec3 v_normal;
out vec3 v_color;
out vec2 v_uv;
void main() {
    v_position = u_rotation * in_position + u_translation;
    v_normal = u_rotation * in_normal;
    v_color = in_color;
    v_uv = in_uv * u_uv_scale;
    gl_Position = u_projection * vec4(v_position, 1.0);
}
"""

# Ambient + per light (diffuse + Blinn-Phong specular) x the lit fraction of a soft
# percentage-closer lookup of its shadow map. The normal is turned towards the camera (back
# faces seen through holes are lit like front faces). Samplers of an array may only be
# indexed by constants in GLSL 3.30, hence one sampler per light. Output 1 is the instance
# id / 255 (0 for planes), alpha 1 marks every drawn pixel.
LIT_FRAGMENT = """
#version 330
const int MAX_LIGHTS = %d;
uniform int u_light_count;
uniform vec3 u_light_position[MAX_LIGHTS];
uniform vec3 u_light_color[MAX_LIGHTS];
uniform mat4 u_light_matrix[MAX_LIGHTS];
uniform sampler2DShadow u_shadow0;
uniform sampler2DShadow u_shadow1;
uniform sampler2DShadow u_shadow2;
uniform float u_shadow_texel;
uniform vec3 u_ambient;
uniform vec3 u_color_gain;
uniform float u_specular;
uniform float u_shininess;
uniform bool u_textured;
uniform sampler2D u_texture;
uniform float u_instance_id;
in vec3 v_position;
in vec3 v_normal;
in vec3 v_color;
in vec2 v_uv;
layout(location = 0) out vec4 f_color;
layout(location = 1) out float f_id;

float lit_fraction(sampler2DShadow map, vec4 clip) {
    vec3 p = clip.xyz / clip.w * 0.5 + 0.5;
    if (clip.w <= 0.0 || p.x <= 0.0 || p.x >= 1.0 || p.y <= 0.0 || p.y >= 1.0 ||
            p.z >= 1.0) {
        return 1.0;
    }
    // Four bilinear (2x2 percentage-closer) taps half a texel apart: a soft 3x3 edge.
    float h = 0.5 * u_shadow_texel;
    return 0.25 * (texture(map, vec3(p.x - h, p.y - h, p.z)) +
                   texture(map, vec3(p.x + h, p.y - h, p.z)) +
                   texture(map, vec3(p.x - h, p.y + h, p.z)) +
                   texture(map, vec3(p.x + h, p.y + h, p.z)));
}

float lit(int i, vec3 position) {
    vec4 clip = u_light_matrix[i] * vec4(position, 1.0);
    if (i == 0) {
        return lit_fraction(u_shadow0, clip);
    }
    if (i == 1) {
        return lit_fraction(u_shadow1, clip);
    }
    return lit_fraction(u_shadow2, clip);
}

void main() {
    vec3 normal = normalize(v_normal);
    if (dot(normal, v_position) > 0.0) {
        normal = -normal;
    }
    vec3 albedo = v_color * u_color_gain;
    if (u_textured) {
        albedo *= texture(u_texture, v_uv).rgb;
    }
    vec3 view = normalize(-v_position);
    vec3 shade = u_ambient * albedo;
    for (int i = 0; i < MAX_LIGHTS; ++i) {
        if (i >= u_light_count) {
            break;
        }
        vec3 to_light = normalize(u_light_position[i] - v_position);
        float diffuse = dot(normal, to_light);
        if (diffuse <= 0.0) {
            continue;
        }
        vec3 halfway = normalize(to_light + view);
        float specular = u_specular * pow(max(dot(normal, halfway), 0.0), u_shininess);
        shade += lit(i, v_position) * u_light_color[i] * (albedo * diffuse + specular);
    }
    f_color = vec4(clamp(shade, 0.0, 1.0), 1.0);
    f_id = u_instance_id / 255.0;
}
""" % MAX_LIGHTS

# Depth only, from a light: u_light_matrix maps camera-frame points to its clip space.
SHADOW_VERTEX = """
#version 330
uniform mat4 u_light_matrix;
uniform mat3 u_rotation;
uniform vec3 u_translation;
in vec3 in_position;
void main() {
    gl_Position = u_light_matrix * vec4(u_rotation * in_position + u_translation, 1.0);
}
"""

SHADOW_FRAGMENT = """
#version 330
void main() {
}
"""
