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
The students: the detector's and Q-Net's last layers learn from the pseudo-labelled frames.

Both students keep the shared layers as they are and retrain only the layers that read
them, from their shipped values, on features the frozen layers compute once per augmented
copy of each labelled frame (as ``object_rows`` adds an object): a few hundred frames cannot
retrain a trunk, and the frozen trunk cannot forget the renders' features.

* Detector (``adapt_detector``): its 1x1 box head learns the labels' amodal box sides
  (the labels' boxes, projected from refined poses, are truer in size than the detector's
  on real frames); its heatmap head learns too only as ``HeadTraining.heatmap`` says,
  since the labels are the objects the detector already finds: teaching its heatmap on
  them lowers the peaks of the ones it finds less well. There, a label is a CenterNet
  peak at its box centre, and the regions of untrusted poses are left out of the
  background term (``label_set.IgnoreRegions``), since a frame holds more objects than it
  has labels. An L2 pull toward the start weights (``anchor``) keeps the heads near what
  the renders taught.
* Q-Net (``adapt_qnet``): its head rows (all objects) on crops around the labels' boxes,
  jittered as the detector's boxes are, against the labels' rotations
  (``object_rows.fit_new_rows`` with every object's rows).
"""

from collections.abc import Mapping

import numpy as np
import torch
import torch.nn.functional as F

from bbpose_ros.core.adaptation.label_set import IgnoreRegions
from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.nets.detector import CenterBoxNet
from bbpose_ros.core.nets.qnet import QNet
from bbpose_ros.core.training.cache import TrainingCache
from bbpose_ros.core.training.detector_training import (DetectorBatches,
                                                        DetectorTrainSettings, focal_loss,
                                                        to_input_pixels)
from bbpose_ros.core.training.head_fitting import cache_features, fit_tensors
from bbpose_ros.core.training.object_rows import fit_new_rows
from bbpose_ros.core.training.qnet_training import QNetTrainSettings
from bbpose_ros.core.training.settings import HeadTraining, RowTraining


def ignore_mask(regions: IgnoreRegions, scenes: np.ndarray, network: CenterBoxNet,
                cache: TrainingCache) -> torch.Tensor:
    """
    (B, C, h, w) bool: False on the grid cells of ``scenes`` inside an ignore region.

    Cells are judged by their centres, in the detector's input pixels; a region counts in
    its object's channel only.
    """
    config = network.config
    width, height = config.input_size
    stride = config.stride
    cols = np.arange(width // stride) * stride + (stride - 1) / 2.0
    rows = np.arange(height // stride) * stride + (stride - 1) / 2.0
    counted = np.ones((len(scenes), len(config.objects), len(rows), len(cols)), dtype=bool)
    for k, scene in enumerate(scenes):
        for obj, box_uv in regions.of_scene(int(scene)):
            name = cache.objects[obj]
            if name not in config.objects:
                continue
            box = to_input_pixels(box_uv[None], config, cache.camera)[0]
            inside = ((rows[:, None] >= box[1]) & (rows[:, None] <= box[3]) &
                      (cols[None, :] >= box[0]) & (cols[None, :] <= box[2]))
            counted[k, config.objects.index(name)] &= ~inside
    return torch.from_numpy(counted)


def adapt_detector(network: CenterBoxNet, cache: TrainingCache, regions: IgnoreRegions,
                   training: HeadTraining, seed: int = 0,
                   progress: bool = True) -> dict[str, float]:
    """
    Retrain ``network``'s heatmap and box heads in place on a label set.

    Args:
        network: the detector (its trunk and merge layers stay as they are).
        cache: the label set (``label_set.write_label_set``).
        regions: its ignore regions.
        training: HeadTraining.
        seed: seed of the augmentation and batch draws.
        progress: show tqdm bars.

    Returns:
        {'loss_before', 'loss_after'}: the training loss of the heads on the cached
        features (unaugmented first pass), before and after.

    """
    settings = DetectorTrainSettings(val_fraction=0.0, min_visib=0.0)
    batches = DetectorBatches(cache, network.config, settings, seed)
    network.eval()
    scenes = np.arange(len(cache.images))

    def encode(chunk, copy):
        images, heat, sides, weight = batches.make(chunk, 0.0 if copy == 0 else 1.0)
        return (network.features(images), heat, sides, weight,
                ignore_mask(regions, chunk, network, cache))

    chunks = [scenes[i:i + 4] for i in range(0, len(scenes), 4)]
    features, heat, sides, weight, counted = cache_features(encode, chunks, training.passes,
                                                            progress)
    start = [p.detach().clone() for p in (network.heatmap.weight, network.heatmap.bias,
                                          network.box.weight, network.box.bias)]
    learns = (training.heatmap == 'all', training.heatmap != 'none', True, True)

    def loss_of(params, pick, with_anchor=True):
        x = features[pick].float()
        heat_logits = F.conv2d(x, params[0], params[1])
        box_log = F.conv2d(x, params[2], params[3])
        w = weight[pick]
        l1 = (F.l1_loss(box_log, sides[pick], reduction='none').sum(dim=1) * w).sum()
        loss = focal_loss(heat_logits, heat[pick], counted[pick]) + \
            training.box_weight * l1 / w.sum().clamp_min(1)
        if with_anchor:
            loss = loss + training.anchor * sum(((p - s) ** 2).sum()
                                                for p, s in zip(params, start))
        return loss

    first = torch.arange(len(scenes))
    with torch.no_grad():
        before = float(loss_of(start, first, False))
    params = fit_tensors(start, learns, loss_of, len(features), training,
                         np.random.default_rng(seed), 'detector heads', progress)
    with torch.no_grad():
        after = float(loss_of(params, first, False))
        network.heatmap.weight.copy_(params[0])
        network.heatmap.bias.copy_(params[1])
        network.box.weight.copy_(params[2])
        network.box.bias.copy_(params[3])
    return {'loss_before': before, 'loss_after': after}


def adapt_qnet(network: QNet, cache: TrainingCache, models: Mapping[str, ObjectModel],
               rows: RowTraining, seed: int = 0, progress: bool = True) -> dict[str, float]:
    """
    Retrain ``network``'s head rows of every object in place on a label set's crops.

    The crops are cut around the labels' boxes jittered by the detector's box error
    (``QNetTrainSettings.box_sigma``); the targets are the labels' rotations with their
    symmetries and both quaternion signs, as Q-Net's training uses them. Returns Q-Net's
    validation figures on the label set's last tenth of frames (``qnet_validation``).
    """
    settings = QNetTrainSettings(min_visib=0.0, val_fraction=0.1, sign_invariant=True,
                                 augment='strong')
    return fit_new_rows(network, list(network.config.objects), cache, models, settings, rows,
                        seed, progress)
