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

"""Settings of the synthetic scene generator, with defaults shaped like the LM-O test set."""

from dataclasses import asdict, dataclass

from bbpose_ros.core.util.errors import InputError

# Side of a crop cache's stored crops in pixels (Q-Net resizes them to its own input).
STORED_CROP_SIZE = 64


@dataclass(frozen=True)
class SynthConfig:
    """
    What a synthetic scene may contain; every ``*_range`` is an inclusive (low, high) pair.

    Poses: the model origin lies at ``distance_range`` metres from the camera, on the ray
    through a pixel drawn uniformly from the image grown by ``frame_margin`` (a fraction of
    its width and height, so objects may be cut by the border; negative keeps them inside
    it). The camera looks from an
    elevation in ``elevation_range_deg`` above the model's x-y plane (LineMod models stand on
    it, z up), any azimuth and an in-plane rotation (roll about the optical axis, 0 when the
    model's z axis points up in the image) in ``inplane_range_deg``: any by default, or e.g.
    (-60, 60) for upright objects under a roughly upright camera, as in LM-O, whose
    instances are mostly upright. ``cluster_probability`` is the chance
    that a target is put next to an earlier one, ``occluder_probability`` the chance that a
    distractor is put in front of a target. Distractor shapes are ``shape_size_range``
    metres across; ``shape_count`` shapes are made per generator.

    Light: ambient and diffuse intensities, and per-object RGB colour gains. Ambient light
    dominates: LM-O's vertex colours have the studio light baked in, and real LM-O crops
    look flat and bright next to strongly shaded renders.

    Camera effects (images in 0..255): brightness offset, contrast and saturation factors,
    Gaussian blur of sigma ``blur_sigma_range`` pixels with ``blur_probability``, Gaussian
    noise of sigma ``noise_sigma_range``, JPEG compression at ``jpeg_quality_range`` with
    ``jpeg_probability``.
    """

    distance_range: tuple[float, float] = (0.35, 1.5)
    elevation_range_deg: tuple[float, float] = (-15.0, 90.0)
    inplane_range_deg: tuple[float, float] = (0.0, 360.0)
    frame_margin: float = 0.05
    targets_per_image: tuple[int, int] = (4, 8)
    distractors_per_image: tuple[int, int] = (1, 4)
    cluster_probability: float = 0.15
    occluder_probability: float = 0.2
    shape_size_range: tuple[float, float] = (0.03, 0.15)
    shape_count: int = 24
    ambient_range: tuple[float, float] = (0.45, 0.95)
    diffuse_range: tuple[float, float] = (0.1, 0.7)
    color_gain_range: tuple[float, float] = (0.85, 1.15)
    brightness_range: tuple[float, float] = (-25.0, 25.0)
    contrast_range: tuple[float, float] = (0.75, 1.25)
    saturation_range: tuple[float, float] = (0.7, 1.3)
    blur_probability: float = 0.3
    blur_sigma_range: tuple[float, float] = (0.3, 1.5)
    noise_sigma_range: tuple[float, float] = (0.0, 6.0)
    jpeg_probability: float = 0.5
    jpeg_quality_range: tuple[int, int] = (40, 95)

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if '_range' in name:
                if len(value) != 2 or not value[0] <= value[1]:
                    raise InputError(f'synth config {name} must be (low, high) with '
                                     f'low <= high, got {value}')
            elif name.endswith('_probability') and not 0.0 <= value <= 1.0:
                raise InputError(f'synth config {name} must be in [0, 1], got {value}')
        if self.distance_range[0] <= 0.1:
            raise InputError(f'synth config distance_range must start beyond 0.1 m, got '
                             f'{self.distance_range}')
        if self.targets_per_image[0] < 1 or self.distractors_per_image[0] < 0:
            raise InputError('synth config needs at least one target and no negative counts')
        if self.shape_count < 1 or not -0.5 < self.frame_margin:
            raise InputError('synth config shape_count must be >= 1, frame_margin > -0.5')
