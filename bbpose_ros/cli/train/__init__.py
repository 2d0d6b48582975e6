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
``bbpose train``: render a training cache, train the networks, quantise them, run Fig. 3.

One module per stage, each with its parser and its ``run``; ``arguments`` holds the
options they share, ``inputs`` what they load from them.

* ``bbpose train render``: synthetic scenes -> a cache folder (outside the repository, e.g.
  ~/.cache/bbpose/train), resumable; the detector trains on it.
* ``bbpose train render-crops``: object-centred Q-Net crops -> a crop cache folder
  (``--cache``), resumable; Q-Net trains on either kind of cache.
* ``bbpose train import-bop``: annotated images of a BOP split (PBR renders, real frames)
  -> a scene cache, or with ``--kind crops`` a crop cache, resumable; never the evaluation
  frames.
* ``bbpose train detector`` / ``bbpose train qnet``: train from the cache within a step and/or
  time budget, on ``--device`` cpu or cuda; ``--run-dir`` holds checkpoint.pt (resumed, on
  either device), log.csv, train.log, loss.png and the weight file; ``--export`` copies the
  weight file (e.g. to bbpose_ros/weights/).
* ``bbpose train dense``: the dense correspondence net (model coordinates and masks per
  crop cell) on a crop cache rendered with ``--dense-size``.
* ``bbpose train verifier``: the detector's second stage, on the candidates a trained
  detector (``--detector-weights``) finds in a scene cache; writes both stages in one file.
* ``bbpose train quantize``: the int8 graph of the detector or Q-Net (``<weights
  stem>_int8.onnx``), calibrated on a scene cache's renders; the ``inference_precision``
  parameter chooses it at run time.
* ``bbpose train fig3``: the paper's Fig. 3, Q-Net with and without q-normalization, same
  initialisation and samples, losses in one plot.
"""

import argparse

from bbpose_ros.cli.train import (train_dense, train_detector, train_fig3, train_import_bop,
                                  train_qnet, train_quantize, train_render,
                                  train_render_crops, train_verifier)

STAGES = (train_render, train_render_crops, train_import_bop, train_detector, train_qnet,
          train_dense, train_verifier, train_quantize, train_fig3)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``bbpose train`` and its stages, in the order ``--help`` lists them."""
    parser = subparsers.add_parser(
        'train', help='train the detector or Q-Net on renders or annotated BOP images',
        description='Render synthetic training scenes once (or import annotated BOP images), '
                    'then train the learned stages on the CPU or a CUDA GPU.')
    stages = parser.add_subparsers(dest='stage', metavar='STAGE', required=True)
    for stage in STAGES:
        stage.add_parser(stages)
