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
Fingerprints of meshes and other arrays: one SHA-256 for every cache key and record.

A cache named after a mesh (stable poses, viewpoint models) and a record of what a run was
made from both use ``sha256_of_arrays``, so one mesh has one fingerprint.
"""

import hashlib

import numpy as np
import numpy.typing as npt


def sha256_of_arrays(*arrays: npt.ArrayLike, text: str = '') -> str:
    """
    Return the SHA-256 hex digest of the arrays' bytes in C order, then of ``text``.

    The bytes are the arrays' as given: cast them first (float64 vertices, int64 faces) for
    a fingerprint that does not depend on how a mesh was loaded. ``text`` adds the settings
    a cached result was made with.
    """
    digest = hashlib.sha256()
    for array in arrays:
        digest.update(np.ascontiguousarray(array).tobytes())
    digest.update(text.encode())
    return digest.hexdigest()
