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
A transform buffer with tf2's semantics, for a venv without tf2_ros (the ROS-free core).

Transforms arrive as tf2_msgs would carry them: parent frame, child frame, stamp, the
child's origin in the parent (metres) and its rotation (ROS order x, y, z, w). Like tf2's
``BufferCore``:

* a frame has one parent; frames form a tree, and ``lookup`` chains the transforms from
  the source frame up to the common ancestor and down to the target;
* static transforms (``/tf_static``) hold at every time; dynamic ones (``/tf``) are kept
  for ``cache_s`` seconds behind the newest of their frame and interpolated (linearly,
  the rotation by slerp) between the two samples around the asked time; a time outside
  a frame's samples is refused (no extrapolation); time 0 asks for the latest time that
  every dynamic link of the chain has;
* a transform with a non-finite value or a quaternion whose squared norm is off 1 by more
  than ``QUATERNION_TOLERANCE`` is refused (tf2's check), others are normalised; a frame id
  must be non-empty and must not start with '/'.

One difference, for recordings played again: a dynamic sample older than its frame's
newest by more than ``cache_s`` means the clock went back (a bag restarted), and clears
every dynamic sample instead of being dropped as tf2 drops old data (tf2_ros's listener
clears on a clock jumping back).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from bbpose_ros.core.geometry.rigid import invert_rigid, rigid_from_xyzw
from bbpose_ros.core.util.errors import InputError

QUATERNION_TOLERANCE = 1e-2     # |x^2 + y^2 + z^2 + w^2 - 1| above this: refused
MAX_CHAIN = 100                 # more links than this between two frames: a loop


class TransformUnavailable(LookupError):
    """A lookup the buffer cannot answer: frames not connected, or no data at that time."""


@dataclass
class _Link:
    """A frame's transform to its parent over time: sorted stamps, translations, quaternions."""

    parent: str
    static: bool
    stamps: list[int] = field(default_factory=list)
    translations: list[np.ndarray] = field(default_factory=list)
    quaternions: list[np.ndarray] = field(default_factory=list)    # (x, y, z, w)

    def at(self, stamp_ns: int, child: str) -> np.ndarray:
        """(4, 4) parent_from_child at ``stamp_ns`` (0: the newest sample)."""
        if self.static or stamp_ns == 0:
            return rigid_from_xyzw(self.translations[-1], self.quaternions[-1])
        if not self.stamps[0] <= stamp_ns <= self.stamps[-1]:
            direction = 'past' if stamp_ns < self.stamps[0] else 'future'
            raise TransformUnavailable(
                f'{self.parent} -> {child}: time {stamp_ns * 1e-9:.3f} s would need '
                f'extrapolation into the {direction} (data from {self.stamps[0] * 1e-9:.3f} '
                f'to {self.stamps[-1] * 1e-9:.3f} s)')
        right = bisect.bisect_left(self.stamps, stamp_ns)
        if self.stamps[right] == stamp_ns:
            return rigid_from_xyzw(self.translations[right], self.quaternions[right])
        left = right - 1
        share = (stamp_ns - self.stamps[left]) / (self.stamps[right] - self.stamps[left])
        translation = (1 - share) * self.translations[left] + share * self.translations[right]
        quaternion = _slerp(self.quaternions[left], self.quaternions[right], share)
        return rigid_from_xyzw(translation, quaternion)


class TransformBuffer:
    """
    The transforms of a TF tree over the last ``cache_s`` seconds (module docstring).

    Not thread-safe by itself: the node takes a lock around it (callbacks write, the
    worker reads).
    """

    def __init__(self, cache_s: float = 10.0) -> None:
        self.cache_ns = int(cache_s * 1e9)
        self._links: dict[str, _Link] = {}

    def clear(self) -> None:
        """Forget the dynamic transforms; the static ones hold on."""
        self._links = {child: link for child, link in self._links.items() if link.static}

    def set_transform(self, parent: str, child: str, stamp_ns: int,
                      translation: npt.ArrayLike, rotation_xyzw: npt.ArrayLike,
                      static: bool = False) -> bool:
        """
        Add one transform: the child frame's pose in the parent, at ``stamp_ns``.

        Returns True when the sample went back in time (``cache_s`` behind its frame's
        newest) and cleared the dynamic transforms first. Raises InputError naming the
        frames for a transform the buffer refuses (module docstring); the buffer is then
        unchanged.
        """
        translation = np.asarray(translation, dtype=float).reshape(3)
        quaternion = np.asarray(rotation_xyzw, dtype=float).reshape(4)
        where = f'transform {parent!r} -> {child!r}'
        for frame in (parent, child):
            if not frame or frame.startswith('/'):
                raise InputError(f'{where}: frame ids must be non-empty and not start with /')
        if parent == child:
            raise InputError(f'{where}: a frame cannot be its own parent')
        if not (np.all(np.isfinite(translation)) and np.all(np.isfinite(quaternion))):
            raise InputError(f'{where}: not finite')
        norm2 = float(quaternion @ quaternion)
        if abs(norm2 - 1.0) > QUATERNION_TOLERANCE:
            raise InputError(f'{where}: quaternion of squared norm {norm2:.4f}, not a rotation')
        link = self._links.get(child)
        if link is not None and (link.parent != parent or link.static != static):
            if link.static == static:
                raise InputError(f'{where}: {child!r} already has the parent {link.parent!r}')
            link = None                 # static <-> dynamic: the newer kind replaces it
        jumped = False
        if link is not None and not static and stamp_ns < link.stamps[-1] - self.cache_ns:
            self.clear()
            link, jumped = None, True
        if link is None:
            link = self._links[child] = _Link(parent, static)
        quaternion = quaternion / np.sqrt(norm2)
        if static:
            link.stamps, link.translations, link.quaternions = [stamp_ns], [translation], \
                [quaternion]
            return jumped
        index = bisect.bisect_left(link.stamps, stamp_ns)
        if index < len(link.stamps) and link.stamps[index] == stamp_ns:
            link.translations[index], link.quaternions[index] = translation, quaternion
        else:
            link.stamps.insert(index, stamp_ns)
            link.translations.insert(index, translation)
            link.quaternions.insert(index, quaternion)
        keep = bisect.bisect_left(link.stamps, link.stamps[-1] - self.cache_ns)
        del link.stamps[:keep], link.translations[:keep], link.quaternions[:keep]
        return jumped

    def lookup(self, target: str, source: str, stamp_ns: int) -> np.ndarray:
        """
        (4, 4) target_from_source at ``stamp_ns`` (0: the latest common time), metres.

        Raises TransformUnavailable saying why (an unknown frame, frames in two trees, a
        time outside the data).
        """
        if target == source:
            return np.eye(4)
        up_source, up_target = self._chain(source), self._chain(target)
        common = next((frame for frame in up_source if frame in up_target), None)
        if common is None:
            raise TransformUnavailable(f'{target!r} and {source!r} are not connected by TF')
        source_links = up_source[:up_source.index(common)]
        target_links = up_target[:up_target.index(common)]
        if stamp_ns == 0:
            dynamic = [self._links[f].stamps[-1] for f in source_links + target_links
                       if not self._links[f].static]
            stamp_ns = min(dynamic) if dynamic else 0
        common_from_source = self._to_ancestor(source_links, stamp_ns)
        common_from_target = self._to_ancestor(target_links, stamp_ns)
        return invert_rigid(common_from_target) @ common_from_source

    def _chain(self, frame):
        """[frame, its parent, ..., the root]."""
        chain = [frame]
        while frame in self._links:
            frame = self._links[frame].parent
            chain.append(frame)
            if len(chain) > MAX_CHAIN:
                raise TransformUnavailable(f'a loop in the TF tree above {chain[0]!r}')
        if len(chain) == 1 and not any(link.parent == frame for link in self._links.values()):
            raise TransformUnavailable(f'frame {frame!r} is not in the TF tree')
        return chain

    def _to_ancestor(self, frames, stamp_ns):
        """(4, 4) ancestor_from_frame along the links of ``frames`` (each to its parent)."""
        transform = np.eye(4)
        for frame in frames:
            transform = self._links[frame].at(stamp_ns, frame) @ transform
        return transform


def _slerp(q0, q1, share):
    """Spherical interpolation of unit quaternions (either order), the shorter way."""
    dot = float(q0 @ q1)
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + share * (q1 - q0)
        return q / np.linalg.norm(q)
    angle = np.arccos(dot)
    return (np.sin((1 - share) * angle) * q0 + np.sin(share * angle) * q1) / np.sin(angle)
