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
``load_pipeline``: the PosePipeline of the learned stages, from two weight files and options.

The node, ``bbpose eval`` and ``bbpose bench`` build their pipelines here, so what runs is
the same everywhere: the detector (``box_detector``), Q-Net (``rotation_estimator``), the
hypothesis ranking, the Bounding Box Equation and, with ``options.refine``, the refiner
(``refinement``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from bbpose_ros.core.errors import InputError
from bbpose_ros.core.inference.int8_graphs import (cpu_has_int8_dot, int8_graph_path,
                                                   read_int8_graph)
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
from bbpose_ros.core.refine.viewpoint_cache import load_viewpoint_models

if TYPE_CHECKING:
    from bbpose_ros.core.data.models import ObjectModel

# Largest Q-Net batch run at load time (see QNetRotationEstimator.warm_up).
MAX_WARM_UP_BATCH = 16


def load_pipeline(models: Mapping[str, ObjectModel],
                  options: PipelineOptions | None = None,
                  detector_weights: Path | str | None = None,
                  qnet_weights: Path | str | None = None,
                  refiner_log: Callable[[str], None] | None = None,
                  dense_weights: Path | str | None = None) -> PosePipeline:
    """
    Build a PosePipeline with the learned detector and Q-Net, warmed up.

    Args:
        models: {name: ObjectModel}; every name must be covered by both weight files.
        options: PipelineOptions (default: the shipped settings).
        detector_weights: detector file (default: the shipped ``weights/detector.pt``).
        qnet_weights: Q-Net file (default: the shipped ``weights/qnet.pt``).
        refiner_log: gets a line for each viewpoint model the refiner builds (once per
            mesh, then cached).
        dense_weights: dense net file, read when the options use it (``runs_dense``;
            default: the shipped ``weights/dense.pt``).

    Raises:
        InputError: a missing, corrupt or mismatched weight file.

    """
    options = options or PipelineOptions()
    threads = options.threads or None
    if threads is not None:
        torch.set_num_threads(threads)
    names = list(models)
    refiner = None
    if options.refine:
        refiner = load_pose_refiner(models, options.refiner_config,
                                    min_score=options.refine_min_score, progress=False,
                                    log=refiner_log,
                                    mask_choice_weight=options.refine_mask_choice_weight)
    agreement = None
    if options.ranks_by_mask:     # the silhouettes come from the refiner's viewpoint models
        agreement = MaskAgreement(refiner.viewpoint_models if refiner is not None else
                                  load_viewpoint_models(models, progress=False, log=refiner_log))
    selector = HypothesisSelector(models, options.box_consistency_weight,
                                  mask_weight=options.mask_consistency_weight,
                                  agreement=agreement)
    detector_weights = detector_weights or DEFAULT_DETECTOR_WEIGHTS
    detector = BoxDetector(
        load_network(detector_weights, 'detector', names), names, options.score_threshold,
        options.max_instances, options.backend, options.device, threads,
        int8_graph=int8_graph(options, detector_weights, 'detector'))
    rotation = correspondences = None
    if options.uses_qnet:
        qnet_weights = qnet_weights or DEFAULT_QNET_WEIGHTS
        qnet = load_network(qnet_weights, 'qnet', names)
        # Every hypothesis is needed when they are ranked by box or mask or several refined.
        ranked = selector.weight > 0 or options.ranks_by_mask or \
            options.candidates_per_detection > 1
        rotation = QNetRotationEstimator(qnet, options.backend, options.device, threads,
                                         all_hypotheses=qnet.config.hypotheses > 1 and ranked,
                                         int8_graph=int8_graph(options, qnet_weights, 'qnet'))
        rotation.warm_up(_warm_up_batch(models, options))
    if options.runs_dense:
        correspondences = load_correspondences(models, options, dense_weights)
    detector.warm_up()
    return PosePipeline(models, detector, rotation, hypothesis_selector=selector,
                        refiner=refiner, candidates=options.candidates_per_detection,
                        correspondences=correspondences, dense_poses=options.uses_dense,
                        dense_translation=options.dense_translation,
                        dense_mask=options.dense_mask)


def load_correspondences(models: Mapping[str, ObjectModel], options: PipelineOptions,
                         dense_weights: Path | str | None = None
                         ) -> DenseCorrespondenceEstimator:
    """Build the dense stage of ``models`` from a weight file (default: the shipped one)."""
    network = load_network(dense_weights or DEFAULT_DENSE_WEIGHTS, 'dense', list(models))
    stage = DenseCorrespondenceEstimator(network, models, options.backend, options.device,
                                         options.threads or None)
    stage.warm_up(_warm_up_batch(models, options))
    return stage


def int8_graph(options: PipelineOptions, weights: Path | str, network: str):
    """
    Return the int8 graph ``network`` runs under ``options.precision``, or None (float).

    'int8' reads ``int8_graphs.int8_graph_path(weights)`` and raises InputError when it is
    missing or made from other weights; 'auto' takes it only with the onnxruntime backend on
    a CPU with int8 dot products, and where it is missing or does not fit runs the float
    network.
    """
    if options.precision == 'fp32' or options.backend != 'onnxruntime':
        return None
    path = int8_graph_path(weights)
    if options.precision == 'int8':
        return read_int8_graph(path, weights, network)
    if not cpu_has_int8_dot():
        return None
    try:
        return read_int8_graph(path, weights, network)
    except InputError:
        return None


def _warm_up_batch(models, options):
    """Return the largest crop batch a frame can bring: every object's instances, bounded."""
    return min(len(models) * options.max_instances, MAX_WARM_UP_BATCH)
