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
Headless rendering of coloured meshes: an OpenGL renderer and a numpy test oracle.

``MeshRenderer`` draws with moderngl on a standalone EGL context (Mesa llvmpipe on the CPU).
``reference`` is a slow, simple numpy z-buffer used to check it. Both follow OpenCV's pixel
convention of ``CameraIntrinsics``: the centre of pixel (col, row) is at (u, v) = (col, row),
and a pixel belongs to a silhouette when its centre lies inside a projected triangle.
"""

from bbpose_ros.core.render.clip_space import opengl_projection
from bbpose_ros.core.render.gl_renderer import Draw, Lighting, MeshRenderer, RenderResult
from bbpose_ros.core.render.mesh import RenderMesh

__all__ = ['Draw', 'Lighting', 'MeshRenderer', 'RenderMesh', 'RenderResult', 'opengl_projection']
