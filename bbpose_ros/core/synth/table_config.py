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
Settings of the table-top scenes (``table_scenes``), shaped like the LM-O test scene.

The camera ranges were read off the ground-truth poses of the LM-O dev frames (a fact of
the capture, not training data; docs/experiments.md): the table plane from the upright
objects' z axes and lowest points, the camera 0.65-1.21 m from the objects' centroid, 9-77
deg above the table plane, rolled -52..38 deg from upright; 6-8 of the 8 objects in view,
spread up to 0.28-0.56 m from their centroid.
"""

from dataclasses import asdict, dataclass, field
import math

from bbpose_ros.core.synth.config import SynthConfig
from bbpose_ros.core.util.errors import InputError

# Camera effects of the table scenes: blur and noise of a Kinect-like sensor.
TABLE_EFFECTS = SynthConfig(blur_probability=0.5, blur_sigma_range=(0.3, 1.2),
                            noise_sigma_range=(1.0, 6.0))


@dataclass(frozen=True)
class TableConfig:
    """
    What a table-top scene may contain; every ``*_range`` is an inclusive (low, high) pair.

    Layout: ``targets_per_image`` target objects and ``clutter_per_image`` clutter meshes
    (the other meshes and ``shape_count`` random shapes ``shape_size_range`` metres
    across) rest on the table, without touching, in a disc of radius
    ``cluster_radius_range`` metres (grown where it is full), in random order (the
    defaults give about LM-O's histogram of visible fractions); a mesh stands upright (its
    model z axis up, as the LM-O objects stand) with ``upright_probability``, else in one
    of its stable poses, turned about the vertical at random. With ``clutter`` False the
    clutter is drawn and then left out of the image (the same scene otherwise: for
    measuring what clutter is worth).

    Camera: it looks at a point of the cluster (within ``look_offset`` x its radius of the
    centre) from ``camera_distance_range`` metres, ``camera_elevation_range_deg`` above the
    table, any azimuth, rolled by ``inplane_range_deg`` about its optical axis (0: the
    table's normal points up in the image).

    Room: a textured table of half side ``table_half_size_range`` metres, its texture
    repeating every ``texture_tile_range`` metres, and with ``wall_probability`` a
    textured wall behind the cluster ``wall_distance_range`` metres from its centre;
    beyond them a background image.

    Light: ambient ``ambient_range`` plus ``lights_per_image`` point lights of intensity
    ``light_range``, ``light_height_range`` metres above the table and up to
    ``light_spread`` metres to the side, casting shadows unless ``shadows`` is False (the
    same scene otherwise: for measuring what shadows are worth). Materials: per mesh a
    brightness gain drawn log-uniformly from ``brightness_range`` times RGB colour gains
    from ``color_gain_range`` (a scanned mesh's colours can be far off the real object's:
    wide ranges teach shape over colour; a fixed range such as the default (1, 1) draws
    nothing, so older seeds render as before), Blinn-Phong highlights of strength
    ``specular_range`` and exponent ``shininess_range`` (drawn log-uniformly: rough to
    glossy).

    Camera effects: per-channel white-balance gains ``white_balance_range``, a gamma in
    ``gamma_range``, then those of ``effects`` (a ``SynthConfig``: colour jitter, blur,
    noise, JPEG).
    """

    targets_per_image: tuple[int, int] = (6, 8)
    clutter_per_image: tuple[int, int] = (10, 18)
    clutter: bool = True
    cluster_radius_range: tuple[float, float] = (0.12, 0.25)
    upright_probability: float = 0.8
    shape_count: int = 24
    shape_size_range: tuple[float, float] = (0.05, 0.3)
    camera_distance_range: tuple[float, float] = (0.65, 1.25)
    camera_elevation_range_deg: tuple[float, float] = (8.0, 78.0)
    inplane_range_deg: tuple[float, float] = (-45.0, 35.0)
    look_offset: float = 0.6
    table_half_size_range: tuple[float, float] = (0.5, 1.5)
    texture_tile_range: tuple[float, float] = (0.3, 1.5)
    wall_probability: float = 0.6
    wall_distance_range: tuple[float, float] = (0.5, 1.5)
    ambient_range: tuple[float, float] = (0.35, 0.75)
    lights_per_image: tuple[int, int] = (1, 3)
    light_range: tuple[float, float] = (0.15, 0.5)
    light_height_range: tuple[float, float] = (0.9, 2.0)
    light_spread: float = 1.5
    shadows: bool = True
    brightness_range: tuple[float, float] = (1.0, 1.0)
    color_gain_range: tuple[float, float] = (0.85, 1.15)
    specular_range: tuple[float, float] = (0.0, 0.5)
    shininess_range: tuple[float, float] = (4.0, 128.0)
    white_balance_range: tuple[float, float] = (0.88, 1.12)
    gamma_range: tuple[float, float] = (0.8, 1.25)
    effects: SynthConfig = field(default_factory=lambda: TABLE_EFFECTS)

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if '_range' in name or name.endswith('_per_image'):
                if len(value) != 2 or not all(map(math.isfinite, value)) or \
                        not value[0] <= value[1]:
                    raise InputError(f'table config {name} must be finite (low, high) with '
                                     f'low <= high, got {value}')
            elif name.endswith('_probability') and not 0.0 <= value <= 1.0:
                raise InputError(f'table config {name} must be in [0, 1], got {value}')
        if self.targets_per_image[0] < 1 or self.clutter_per_image[0] < 0:
            raise InputError('table config needs at least one target and no negative counts')
        if self.lights_per_image[1] > 3 or self.lights_per_image[0] < 0:
            raise InputError(f'table config lights_per_image must lie in 0..3, got '
                             f'{self.lights_per_image}')
        if self.camera_distance_range[0] <= 0.2 or self.shape_count < 1:
            raise InputError('table config camera_distance_range must start beyond 0.2 m and '
                             'shape_count be >= 1')
        if not 0 <= self.camera_elevation_range_deg[0] <= \
                self.camera_elevation_range_deg[1] <= 90:
            raise InputError(f'table config camera_elevation_range_deg must lie in 0..90, '
                             f'got {self.camera_elevation_range_deg}')
        for name in ('brightness_range', 'shininess_range'):  # drawn log-uniformly
            if getattr(self, name)[0] <= 0.0:
                raise InputError(f'table config {name} must be > 0, got '
                                 f'{getattr(self, name)}')
        if self.color_gain_range[0] < 0.0:
            raise InputError(f'table config color_gain_range must be >= 0, got '
                             f'{self.color_gain_range}')
        if self.light_height_range[0] <= self.cluster_radius_range[1] + 0.3:
            raise InputError('table config lights must hang above the shadow sphere: '
                             'light_height_range[0] > cluster radius + 0.3 m')
