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

"""What the ``bbpose train`` stages load from their options: caches, meshes, camera, init."""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from bbpose_ros.cli.settings_options import settings_made
from bbpose_ros.core.training.settings import QNetTrainSettings
from bbpose_ros.core.util.errors import InputError

if TYPE_CHECKING:
    import torch

    from bbpose_ros.core.data.models import ObjectModel
    from bbpose_ros.core.geometry.camera import CameraIntrinsics
    from bbpose_ros.core.nets.qnet import QNetConfig
    from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.crop_cache import CropCache


def load_cache(args: argparse.Namespace,
               ) -> tuple[TrainingCache | CropCache, dict[str, ObjectModel]]:
    """Open ``--cache`` (and ``--extra-cache``), scene or crop cache; load its meshes."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.crop_cache import CropCache, is_crop_cache
    folders = [args.cache, *getattr(args, 'extra_cache', ())]
    if is_crop_cache(args.cache):
        cache = CropCache(folders, args.max_shards)
    else:
        cache = TrainingCache(folders, args.max_shards)
    models = load_bop_models(args.dataset, args.objects or cache.objects)
    return cache, models


def init_network(args: argparse.Namespace, kind: str,
                 objects: Iterable[str]) -> torch.nn.Module | None:
    """Load the trained network of ``--init`` (checked: kind, objects), or return None."""
    if args.init is None:
        return None
    from bbpose_ros.core.inference.weights import load_network
    return load_network(args.init, kind, list(objects))


def other_models(args: argparse.Namespace,
                 models: dict[str, ObjectModel]) -> dict[str, ObjectModel]:
    """{name: ObjectModel} the dataset's meshes that are not targets: table-top clutter."""
    from bbpose_ros.core.data.models import load_bop_models
    return {name: model for name, model in load_bop_models(args.dataset).items()
            if name not in models}


def photos(args: argparse.Namespace) -> PhotoBackgrounds | None:
    """Return the photographs of ``--backgrounds``, or None without them."""
    from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds
    return None if not args.backgrounds else PhotoBackgrounds.from_folders(args.backgrounds)


def cache_camera(dataset_dir: Path | str) -> CameraIntrinsics:
    """
    Return the camera of a dataset's caches: its first test frame's, else camera.json's.

    Rendered and imported caches of one dataset get the same camera, so they mix.
    """
    from bbpose_ros.core.data.bop import BopDataset, load_camera
    if not Path(dataset_dir).is_dir():
        raise InputError(f'dataset folder not found: {dataset_dir}')
    if not (Path(dataset_dir) / 'test').is_dir():
        return load_camera(dataset_dir)
    frames = BopDataset(dataset_dir).frames()
    return frames[0].camera if frames else load_camera(dataset_dir)


def qnet_setup(args: argparse.Namespace) -> tuple[
        TrainingCache | CropCache, dict[str, ObjectModel], QNetConfig, QNetTrainSettings]:
    """Return Q-Net's cache, meshes, config and train settings from the options."""
    from bbpose_ros.core.nets.qnet import QNetConfig
    if args.hypotheses < 1:
        raise InputError(f'--hypotheses must be at least 1, got {args.hypotheses}')
    measured = None if args.box_sigma_from is None else _measured_sigma(args.box_sigma_from)
    given = {} if measured is None or args.box_sigma is not None else {'box_sigma': measured}
    settings = settings_made(QNetTrainSettings, args, **given)
    cache, models = load_cache(args)
    try:
        config = QNetConfig(tuple(models), crop_size=args.crop_size, channels=args.channels,
                            first_stride=args.first_stride,
                            rotation_target=args.rotation_target, sharing=args.sharing,
                            hypotheses=args.hypotheses, backbone=args.backbone)
    except ValueError as err:
        raise InputError(f'invalid Q-Net options: {err}') from None
    return cache, models, config, settings


def _measured_sigma(path):
    from bbpose_ros.core.inference.weights import read_weights
    metadata, _ = read_weights(path, 'detector')
    sigma = metadata.get('training', {}).get('validation', {}).get('side_sigma')
    if not sigma:
        raise InputError(f'weight file {path}: field "training.validation.side_sigma" is '
                         'missing')
    return float(sigma)
