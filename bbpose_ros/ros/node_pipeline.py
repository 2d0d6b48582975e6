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
What the node's worker runs: the pipeline of a NodeConfig and the message builders of its objects.

Built by the configure transition and again, off the executor thread, by a run-time set of
a ``pipeline`` parameter; the worker takes the current NodePipeline once per frame, so a
rebuild swaps both at once.
"""

from collections.abc import Callable
from dataclasses import dataclass

from bbpose_ros.core.data.models import load_bop_models
from bbpose_ros.core.pipeline.loader import load_pipeline, WeightFiles
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.tracking import PoseTracker
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.conversions import MarkerArrayBuilder
from bbpose_ros.ros.detections import DetectionsBuilder
from bbpose_ros.ros.params import NodeConfig


@dataclass(frozen=True)
class NodePipeline:
    """
    A pipeline and the MarkerArrayBuilder and DetectionsBuilder of its objects.

    ``pipeline`` is a PosePipeline, or a PoseTracker around one (same ``estimate`` and
    ``models``).
    """

    pipeline: PosePipeline | PoseTracker
    markers: MarkerArrayBuilder
    detections: DetectionsBuilder


def stop_background(built: NodePipeline | None, for_good: bool = False) -> None:
    """
    Stop the background job of a NodePipeline's tracker (stream mode), forgetting its tracks.

    Anything else (no tracker, None) is left alone. ``for_good`` (the pipeline is dropped):
    frames it is still given are answered by the tracks alone.
    """
    tracker = getattr(built, 'pipeline', None)
    if isinstance(tracker, PoseTracker):
        if for_good:
            tracker.close()
        else:
            tracker.reset()


def build_node_pipeline(config: NodeConfig,
                        log: Callable[[str], None] | None = None) -> NodePipeline:
    """
    Build the NodePipeline of a NodeConfig: meshes, the learned stages, refinement, tracking.

    ``log`` gets a line naming what runs the detector and Q-Net (fp32 or int8) and one for each
    viewpoint model the refiner builds (once per mesh, then cached). With ``tracking`` the
    pipeline is a PoseTracker around the PosePipeline (``load_pipeline``).

    Raises InputError naming the parameters behind a failure (unknown objects, a weight
    file that does not fit).
    """
    try:
        models = load_bop_models(config.dataset_dir, list(config.objects))
    except InputError as err:
        raise InputError(f'parameter objects / dataset_dir: loading the objects from '
                         f'{config.dataset_dir}: {err}') from err
    try:
        pipeline = load_pipeline(models, config.options, WeightFiles(
            config.detector_weights, config.qnet_weights, config.dense_weights), log=log)
    except InputError as err:
        raise InputError(f'parameters detector_weights / qnet_weights / dense_weights (empty: '
                         f'the shipped files): {err}') from err
    if log is not None:
        stages = getattr(pipeline, 'pipeline', pipeline)      # inside a PoseTracker
        in_place = getattr(pipeline, 'in_place', None)          # stream mode's second route
        log(f'networks: detector {stages.detector.precision}, {_networks(stages)} '
            f'(inference_precision {config.options.inference_precision})'
            + ('' if in_place is None else f'; frames detected in place: pose_source '
               f'{in_place.options.pose_source}, {_networks(in_place)}'))
    return NodePipeline(pipeline, MarkerArrayBuilder(models), DetectionsBuilder(models))


def _networks(stages):
    """Say how a PosePipeline runs Q-Net and the dense net ('not used' where it does not)."""
    qnet = getattr(stages.rotation_estimator, 'precision', 'not used')
    dense = getattr(stages.correspondences, 'precision', 'not used')
    return f'Q-Net {qnet}, dense net {dense}'
