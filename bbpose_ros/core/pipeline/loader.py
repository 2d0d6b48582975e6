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
``load_pipeline``: the PosePipeline of a PipelineOptions, from the weight files.

The node, ``bbpose eval`` and ``bbpose bench`` build their pipelines here, so what runs is
the same everywhere: the detector (``box_detector``), Q-Net (``rotation_estimator``), the
hypothesis ranking, the Bounding Box Equation, the dense net (``correspondences``) where
the options use it, the refiner (``refinement``) with ``refine``, and a PoseTracker
around it all with ``tracking``. ``StagesGiven`` says which stages the ground truth
replaces (``bbpose eval --boxes gt / --rotation gt``): those are not loaded, and every
other stage is the one the options build.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from bbpose_ros.core.inference.backends import use_inference_threads
from bbpose_ros.core.inference.int8_graphs import choose_int8_graph
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.inference.weights import (DEFAULT_DENSE_WEIGHTS, DEFAULT_DETECTOR_WEIGHTS,
                                               DEFAULT_QNET_WEIGHTS, load_network)
from bbpose_ros.core.pipeline.box_detector import BoxDetector
from bbpose_ros.core.pipeline.correspondences import DenseCorrespondenceEstimator
from bbpose_ros.core.pipeline.hypotheses import HypothesisSelector
from bbpose_ros.core.pipeline.mask_agreement import MaskAgreement
from bbpose_ros.core.pipeline.pose_pipeline import PosePipeline
from bbpose_ros.core.pipeline.refinement import load_pose_refiner
from bbpose_ros.core.pipeline.rotation_estimator import QNetRotationEstimator
from bbpose_ros.core.pipeline.stream_schedule import in_place_fallback, stream_routes
from bbpose_ros.core.pipeline.tracking import PoseTracker
from bbpose_ros.core.refine.viewpoint_cache import load_viewpoint_models
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel

# Largest Q-Net batch run at load time (see QNetRotationEstimator.warm_up).
MAX_WARM_UP_BATCH = 16


@dataclass(frozen=True)
class WeightFiles:
    """The weight files of the learned stages; None: the shipped file."""

    detector: Path | str | None = None
    qnet: Path | str | None = None
    dense: Path | str | None = None


@dataclass(frozen=True)
class PipelineFiles:
    """
    What a tool made for the node to load: its objects, their dataset folder, weight files.

    ``bbpose add-object`` and ``bbpose adapt`` return one; ``ros/params_file.py`` turns it
    into the node's parameters. ``dataset_dir`` and the weight files are None where the tool
    leaves the node's value as it was.
    """

    objects: tuple[str, ...]
    dataset_dir: Path | None = None
    weights: WeightFiles = WeightFiles()


@dataclass(frozen=True)
class StagesGiven:
    """
    Which stages the caller replaces by the ground truth, passing their outputs to ``estimate``.

    Attributes:
        boxes: the detections are given: no detector is loaded.
        rotations: the rotations are given: no Q-Net is loaded, and the dense net only where
            its masks are used (``PipelineOptions.runs_dense(rotations_given=True)``).

    """

    boxes: bool = False
    rotations: bool = False


def load_pipeline(models: Mapping[str, ObjectModel], options: PipelineOptions,
                  weights: WeightFiles = WeightFiles(), given: StagesGiven = StagesGiven(),
                  log: Callable[[str], None] | None = None) -> PosePipeline | PoseTracker:
    """
    Build the pipeline of ``options`` with the learned stages, warmed up.

    Args:
        models: {name: ObjectModel}; every name must be covered by the weight files.
        options: the PipelineOptions (``PipelineOptions()``: the shipped settings).
        weights: the weight files.
        given: the stages the ground truth replaces.
        log: gets a line for each viewpoint model the refiner builds (once per mesh, then
            cached), and one where stream mode's in-place route cannot load the shipped
            dense net (the frames detected in place then take ``pose_source``).

    Returns:
        A PosePipeline, or with ``options.tracking`` a PoseTracker around one (same
        ``estimate`` and ``models``); in stream mode with a ``tracking_in_place_pose_source``
        other than ``pose_source``, a second PosePipeline of that route (the same stages)
        detects the frames the camera leaves time for.

    Raises:
        InputError: a missing, corrupt or mismatched weight file.

    """
    use_inference_threads(options)
    names = list(models)
    routes = stream_routes(options)
    refiner = None
    if options.refine:
        refiner = load_pose_refiner(models, options, progress=False, log=log)
    agreement = None
    if any(route.ranks_by_mask for route in routes) and not given.rotations:
        # The silhouettes come from the refiner's viewpoint models.
        agreement = MaskAgreement(refiner.viewpoint_models if refiner is not None else
                                  load_viewpoint_models(models, progress=False, log=log))
    detector = rotation = correspondences = None
    if not given.boxes:
        detector_weights = weights.detector or DEFAULT_DETECTOR_WEIGHTS
        detector = BoxDetector(load_network(detector_weights, 'detector', names), names, options,
                               choose_int8_graph(options, detector_weights, 'detector'))
        detector.warm_up()
    if any(route.uses_qnet for route in routes) and not given.rotations:
        qnet_weights = weights.qnet or DEFAULT_QNET_WEIGHTS
        qnet = load_network(qnet_weights, 'qnet', names)
        # Every hypothesis is needed when they are ranked by box or mask or several refined.
        ranked = options.box_consistency_weight > 0 or agreement is not None or \
            (options.refine and options.refine_hypotheses > 1)
        rotation = QNetRotationEstimator(qnet, options,
                                         all_hypotheses=qnet.config.hypotheses > 1 and ranked,
                                         int8_graph=choose_int8_graph(options, qnet_weights,
                                                                      'qnet'))
        rotation.warm_up(_warm_up_batch(models, options))
    dense = [route.runs_dense(rotations_given=given.rotations) for route in routes]
    if any(dense):
        try:
            correspondences = load_correspondences(models, options, weights.dense)
        except InputError as err:
            kept = in_place_fallback(routes, dense, weights.dense is not None, err, log)
            if kept is None:
                raise
            routes, dense = kept
    pipelines = [PosePipeline(models, route, detector,
                              rotation if route.uses_qnet else None,
                              hypothesis_selector=HypothesisSelector(
                                  models, route, agreement if route.ranks_by_mask else None),
                              refiner=refiner, correspondences=correspondences if runs else None)
                 for route, runs in zip(routes, dense)]
    return PoseTracker(*pipelines) if options.tracking else pipelines[0]


def load_correspondences(models: Mapping[str, ObjectModel], options: PipelineOptions,
                         dense_weights: Path | str | None = None
                         ) -> DenseCorrespondenceEstimator:
    """Build the dense stage of ``models`` from a weight file (default: the shipped one)."""
    network = load_network(dense_weights or DEFAULT_DENSE_WEIGHTS, 'dense', list(models))
    stage = DenseCorrespondenceEstimator(network, models, options)
    stage.warm_up(_warm_up_batch(models, options))
    return stage


def _warm_up_batch(models, options):
    """Return the largest crop batch a frame can bring: every object's instances, bounded."""
    return min(len(models) * options.max_instances, MAX_WARM_UP_BATCH)
