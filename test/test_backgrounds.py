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

"""Training backgrounds: photographs from a folder, procedural patterns, clear errors."""

import cv2
import numpy as np
import pytest

from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds, random_background
from bbpose_ros.core.util.errors import InputError


@pytest.fixture()
def photo_folder(tmp_path):
    """Write two 'photographs' (a red and a blue gradient) into a nested folder."""
    ramp = np.linspace(0, 255, 400, dtype=np.uint8)[None, :, None]
    red = np.zeros((300, 400, 3), np.uint8) + ramp * np.array([0, 0, 1], np.uint8)  # BGR
    (tmp_path / 'sub').mkdir()
    cv2.imwrite(str(tmp_path / 'red.png'), red)
    cv2.imwrite(str(tmp_path / 'sub' / 'blue.jpg'), red[..., ::-1])
    (tmp_path / 'notes.txt').write_text('not an image')
    return tmp_path


def test_photo_regions_come_from_the_photographs(photo_folder):
    photos = PhotoBackgrounds.from_folders([photo_folder])
    assert [p.rsplit('/', 1)[-1] for p in photos.paths] == ['red.png', 'blue.jpg']
    rng = np.random.default_rng(0)
    seen = set()
    for _ in range(20):
        region = photos.region(rng, 48, 64)
        assert region.shape == (48, 64, 3) and region.dtype == np.uint8
        red, blue = region[..., 0].astype(int), region[..., 2].astype(int)
        assert np.all(region[..., 1] < 8)       # both photographs have no green
        seen.add('red' if red.sum() > blue.sum() else 'blue')
    assert seen == {'red', 'blue'}


def test_backgrounds_are_deterministic_with_or_without_photos(photo_folder):
    photos = PhotoBackgrounds.from_folders([photo_folder])
    for source in (None, photos):
        first = random_background(np.random.default_rng(5), 60, 80, source)
        again = random_background(np.random.default_rng(5), 60, 80, source)
        assert first.shape == (60, 80, 3)
        np.testing.assert_array_equal(first, again)


def test_a_folder_without_photographs_is_a_clear_error(tmp_path):
    (tmp_path / 'notes.txt').write_text('no images here')
    with pytest.raises(InputError, match='no .jpg/.png/.webp images'):
        PhotoBackgrounds.from_folders([tmp_path])
    (tmp_path / 'broken.jpg').write_bytes(b'not a jpeg')
    photos = PhotoBackgrounds.from_folders([tmp_path])
    with pytest.raises(InputError, match='cannot read background image .*broken.jpg'):
        photos.region(np.random.default_rng(0), 10, 10)
