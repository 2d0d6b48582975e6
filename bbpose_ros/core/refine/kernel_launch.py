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
How the refinement's compiled kernels are built and launched: flags, threads, a lock.

The region modality's per-line loops walk each of a few thousand lines pixel by pixel; as
numpy broadcasts that took many large temporary arrays a call, so they run compiled
(``numba.njit(**KERNEL_FLAGS)``, cached on disk after the first compilation) and touch each
pixel once. ``region_modality`` owns the method; the kernels only evaluate it, one module
for each thing they model: ``contour_projection`` (the contour of each pose's closest view
in the image, and the points of it that a nearer instance hides), ``line_histograms`` (the
colours beside the contour), ``line_distributions`` (where the contour lies on each line)
and ``line_gradient`` (the pull on each pose). This module holds what they share: the
compilation flags, the number of threads their per-pose loops run on (``use_threads``: the
setting ``refine_threads``) and whether a parallel kernel must wait for another thread's
(``parallel_launch``).

Threads wait for work asleep, not spinning (``OMP_WAIT_POLICY=PASSIVE`` unless the
environment sets it, before numba starts its OpenMP threads): on a robot's two cores the
other processes (DDS, the camera driver) then keep their core, and a spinning worker does not
slow the refinement down when that core is busy.

Two threads may refine at once (stream mode: the tracks in the foreground, the full
pipeline beside them). numba's OpenMP and TBB threading layers take parallel kernels
launched from several threads at once; its 'workqueue' layer (the one left where neither
library loads) aborts the process on such a launch, so there the parallel kernels are
launched one at a time (``parallel_launch``).
"""

import contextlib
import os
import threading

import numba

os.environ.setdefault('OMP_WAIT_POLICY', 'PASSIVE')

# Fast-math without 'nnan' / 'ninf': the colour loops test for NaN coordinates.
KERNEL_FLAGS = {'cache': True, 'nogil': True, 'error_model': 'numpy',
                'fastmath': {'nsz', 'arcp', 'contract', 'afn', 'reassoc'}}


def use_threads(refine_threads: int) -> None:
    """Run this thread's kernels on ``refine_threads`` (0: one per core, numba's default)."""
    numba.set_num_threads(min(refine_threads, numba.config.NUMBA_NUM_THREADS)
                          if refine_threads > 0 else numba.config.NUMBA_NUM_THREADS)


_LAUNCHES = threading.Lock()
_CONCURRENT_LAYERS = ('omp', 'tbb')
_concurrent: bool | None = None     # known once a parallel kernel has run


def concurrent_launches_safe() -> bool:
    """Tell whether numba's threading layer takes parallel kernels from several threads."""
    global _concurrent
    if _concurrent is None:
        try:
            layer = numba.threading_layer()
        except ValueError:      # no parallel kernel has run yet: the layer is not chosen
            return False
        _concurrent = layer in _CONCURRENT_LAYERS
    return _concurrent


def parallel_launch() -> contextlib.AbstractContextManager:
    """Return what a parallel kernel's launch runs under: a shared lock where it must."""
    return contextlib.nullcontext() if concurrent_launches_safe() else _LAUNCHES
