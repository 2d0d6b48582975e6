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
config/bbpose.yaml, the node's parameters file, written from the parameters' declarations.

Every parameter of ``ros/params.py`` PARAMETERS comes out in its order, with its default as
the value and one comment: its description (for a pipeline setting, ``PipelineOptions``'
in ``core/inference/options.py``), its range and when the node reads it. ``make config``
writes the file (``python -m bbpose_ros.cli.config_file``), ``--check`` compares, and a
test fails when the file and the declarations differ.
"""

import argparse
from collections.abc import Sequence
from pathlib import Path
import sys
import textwrap

from bbpose_ros.core.inference.options import SETTINGS
from bbpose_ros.core.util.files import atomic_output
from bbpose_ros.ros.param_specs import ParameterSpec
from bbpose_ros.ros.params import PARAMETERS
from bbpose_ros.ros.params_file import INDENT, params_file_text, yaml_value

CONFIG_FILE = Path(__file__).resolve().parents[2] / 'config' / 'bbpose.yaml'
WIDTH = 92
KEEP = '\u00a0'    # a space the comment is not wrapped at (within a range)

HEADER = """\
# Parameters of bbpose_node (bbpose_ros). Use with
#   bbpose_node --ros-args --params-file config/bbpose.yaml [-p name:=value ...]
# or launch/bbpose.launch.py. `-p` on the command line overrides this file.
#
# Written by `make config` from the declarations: the pipeline's settings in
# bbpose_ros/core/inference/options.py (PipelineOptions, also the options of bbpose eval and
# bbpose bench), the node's own parameters in bbpose_ros/ros/params.py. Change them there;
# a test fails when this file differs from what they make.
#
# Types are strict: a value of another type (e.g. `1` where a float is expected, write `1.0`)
# is refused at start with a clear error and a non-zero exit code. When each is read:
#   "Start": once, when the process starts.
#   "Configure": by the configure transition; a run-time set is refused unless the node is
#     unconfigured (deactivate and clean it up, set, configure and activate again).
#   "Pipeline": may be set while the node runs: the reply says whether the value is taken;
#     the node then rebuilds its pipeline in the background, answering frames with the old
#     one meanwhile, and swaps the new one in when built ("pipeline rebuilt for ..." in the
#     log; a build that fails sets the values back and logs why).
#   "Frame": read for every frame; may be set at any time.
# A refused run-time set is logged, counted (/diagnostics warnings_parameters_refused) and
# its reply gives the reason.
#
# Topics (relative names; remap them with --ros-args -r image:=/my/image ...):
#   in:  image (sensor_msgs/Image: rgb8, bgr8, mono8, rgba8, bgra8 or 8-bit Bayer), or
#        with image_transport compressed image/compressed (sensor_msgs/CompressedImage:
#        jpeg or png; remap the base, image:=/my/image, as image_transport does)
#        camera_info (sensor_msgs/CameraInfo)
#   out: ~/<object>/pose (geometry_msgs/PoseStamped, metres, quaternion x y z w)
#        ~/detections (vision_msgs/Detection3DArray, one Detection3D per pose)
#        /tf (tf2_msgs/TFMessage, with publish_tf: image frame -> <tf_prefix><object>)
#        ~/markers (visualization_msgs/MarkerArray), ~/debug_image (sensor_msgs/Image),
#        /diagnostics (diagnostic_msgs/DiagnosticArray, 1 Hz)
# All outputs carry the image's header stamp and frame_id.

"""


def parameter_comment(name: str, spec: ParameterSpec) -> str:
    """Return the one comment of a parameter: description, range, node default, when read."""
    parts = [spec.description]
    if spec.value_range is not None:
        low, high = spec.value_range
        parts.append(f'Range {yaml_value(low)} .. {yaml_value(high)}.'.replace(' ', KEEP))
    if spec.option and spec.default != SETTINGS[name].default:
        shared = yaml_value(SETTINGS[name].default)
        parts.append(f"The node's own default; bbpose eval's is {shared}.")
    parts.append(f'{spec.applies.capitalize()}.')
    return textwrap.fill(' '.join(parts), WIDTH, initial_indent=f'{INDENT}# ',
                         subsequent_indent=f'{INDENT}# ',
                         break_on_hyphens=False).replace(KEEP, ' ')


def config_text() -> str:
    """Return the text of config/bbpose.yaml as the declarations make it."""
    return params_file_text({name: spec.default for name, spec in PARAMETERS.items()}, HEADER,
                            {name: parameter_comment(name, spec)
                             for name, spec in PARAMETERS.items()})


def main(argv: Sequence[str] | None = None) -> int:
    """Write config/bbpose.yaml (or the given path); with --check, compare instead."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('path', nargs='?', type=Path, default=CONFIG_FILE,
                        help='the parameters file (default %(default)s)')
    parser.add_argument('--check', action='store_true',
                        help='exit 1 when the file differs from the declarations')
    args = parser.parse_args(argv)
    text = config_text()
    if args.check:
        current = args.path.read_text() if args.path.is_file() else ''
        if current != text:
            print(f'{args.path} differs from the declarations; run `make config`')
            return 1
        return 0
    with atomic_output(args.path) as tmp:
        tmp.write_text(text)
    print(f'wrote {args.path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
