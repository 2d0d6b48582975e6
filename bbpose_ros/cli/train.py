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
``bbpose train``: render a training cache, train the detector or Q-Net, run Fig. 3.

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
import json
import os
from pathlib import Path

from bbpose_ros.cli.common import (add_dataset_argument, add_inplane_argument,
                                   add_objects_argument, float_pair, with_inplane_range)
from bbpose_ros.core.data.bop import DEFAULT_DATASET
from bbpose_ros.core.errors import InputError
from bbpose_ros.core.nets.efficientnet_lite import BACKBONES
from bbpose_ros.core.nets.qnet import QNetConfig
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.training.augment import AUGMENT_STYLES
from bbpose_ros.core.training.device import DEVICES, training_device

QNET_CHANNELS = QNetConfig.__dataclass_fields__['channels'].default
VERIFIER_CHANNELS = (12, 24, 48, 48)
SCENE_STYLES = ('random', 'table')
DEFAULT_CACHE = Path(os.environ.get('BBPOSE_CACHE', Path.home() / '.cache/bbpose/train'))


def add_parser(subparsers):
    """Register ``bbpose train`` and its sub-subcommands."""
    parser = subparsers.add_parser(
        'train', help='train the detector or Q-Net on renders or annotated BOP images',
        description='Render synthetic training scenes once (or import annotated BOP images), '
                    'then train the learned stages on the CPU or a CUDA GPU.')
    sub = parser.add_subparsers(dest='stage', metavar='STAGE', required=True)

    render = sub.add_parser('render', help='render a training cache')
    _common(render)
    render.add_argument('--scenes', type=int, default=6000, help='scenes to render')
    render.add_argument('--workers', type=int, default=2, help='rendering processes')
    render.add_argument('--scene-style', choices=SCENE_STYLES, default='random',
                        help="'random': objects floating at random poses over a background "
                             "among distractors; 'table': objects resting on a textured "
                             'table among clutter, lit with shadows and highlights, seen '
                             'from above like LM-O (default %(default)s)')
    _input_size_option(render)
    _backgrounds_option(render)
    add_inplane_argument(render)
    _table_options(render)
    render.set_defaults(func=run_render)

    crops = sub.add_parser('render-crops', help='render a Q-Net crop cache')
    _common(crops)
    crops.add_argument('--crops', type=int, default=80000,
                       help="crops to render ('random' style)")
    crops.add_argument('--scene-style', choices=SCENE_STYLES, default='random',
                       help="'random': each crop rendered alone around a floating object; "
                            "'table': whole table-top scenes (as 'bbpose train render "
                            "--scene-style table'), a crop cut around every target at least "
                            '15 %% visible (default %(default)s)')
    crops.add_argument('--scenes', type=int, default=None,
                       help="table scenes to render ('table' style; each gives about 5 crops)")
    crops.add_argument('--workers', type=int, default=2, help='rendering processes')
    crops.add_argument('--dense-size', type=int, default=0, metavar='M',
                       help="also store the dense head's targets (model coordinates, visible "
                            'and amodal masks) on an M x M grid per crop; M must divide twice '
                            'the crop size (default 0: none, a version-1 cache)')
    _crop_options(crops)
    _backgrounds_option(crops)
    add_inplane_argument(crops)
    _table_options(crops)
    crops.set_defaults(func=run_render_crops)

    bop = sub.add_parser('import-bop', help='fill a training cache from annotated BOP images',
                         description='Fill a scene cache (detector) or a crop cache (Q-Net) '
                                     'from the annotated images of a BOP split: PBR renders '
                                     'such as train_pbr, real frames, your own captures. '
                                     'Meshes and the cache camera come from --dataset. The '
                                     "dataset's evaluation frames are refused.")
    _common(bop)
    bop.add_argument('--images', type=Path, required=True,
                     help='BOP folder holding camera.json and the split')
    bop.add_argument('--split', required=True, help='split folder name, e.g. train_pbr')
    bop.add_argument('--kind', choices=('scenes', 'crops'), default='scenes',
                     help="'scenes': the detector's scene cache (Q-Net trains on it too); "
                          "'crops': a Q-Net crop cache (default %(default)s)")
    bop.add_argument('--workers', type=int, default=2, help='importing processes')
    _input_size_option(bop)
    _crop_options(bop)
    bop.set_defaults(func=run_import_bop)

    for stage, func in (('detector', run_detector), ('qnet', run_qnet)):
        stage_parser = sub.add_parser(stage, help=f'train the {stage}')
        _common(stage_parser)
        _budget(stage_parser)
        stage_parser.set_defaults(func=func)
    _extra_cache_option(sub.choices['detector'], 'scene')
    _detector_options(sub.choices['detector'])
    qnet = sub.choices['qnet']
    _qnet_options(qnet)
    _init_option(qnet)
    dense = sub.add_parser('dense', help='train the dense correspondence net',
                           description='Train the dense net (model coordinates, visible and '
                                       'amodal masks per cell of a crop) on crop caches '
                                       'rendered with "render-crops --dense-size".')
    _common(dense)
    _budget(dense, steps=8000)
    _dense_options(dense)
    dense.set_defaults(func=run_dense)
    verifier = sub.add_parser('verifier', help="train the detector's second stage")
    _common(verifier)
    _budget(verifier, steps=8000)
    _verifier_options(verifier)
    verifier.set_defaults(func=run_verifier)
    quantize = sub.add_parser(
        'quantize', help='quantise the detector or Q-Net to int8',
        description='Write the int8 graph of a detector or Q-Net weight file (ONNX Runtime '
                    'static quantisation), its activation ranges measured on renders of a '
                    'scene cache; the node runs it with inference_precision int8 (or auto).')
    quantize.add_argument('--network', choices=('detector', 'qnet'), required=True,
                          help='which network')
    quantize.add_argument('--weights', type=Path, default=None,
                          help='float weight file (default: the shipped detector.pt or '
                               'qnet.pt)')
    quantize.add_argument('--cache', type=Path, required=True,
                          help='scene cache whose renders calibrate (never real evaluation '
                               'frames)')
    quantize.add_argument('--inputs', type=int, default=None,
                          help='calibration inputs: frames for the detector (default 32), '
                               'instance crops for Q-Net (default 256)')
    quantize.add_argument('--out', type=Path, default=None,
                          help='the .onnx to write (default: <weights stem>_int8.onnx beside '
                               'the weights)')
    quantize.set_defaults(func=run_quantize)
    fig3 = sub.add_parser('fig3', help="the paper's Fig. 3: with vs without q-normalization")
    _common(fig3)
    _budget(fig3, steps=3000)
    _qnet_options(fig3)
    fig3.set_defaults(func=run_fig3)


def _input_size_option(parser):
    parser.add_argument('--input-size', type=_int_tuple, default=(320, 240), metavar='W,H',
                        help="the detector's input size the frames are stored at; multiples "
                             'of 16 (default 320,240)')


def _crop_options(parser):
    parser.add_argument('--crop-size', type=int, default=64,
                        help='stored crop side (Q-Net resizes to its own)')
    parser.add_argument('--context', type=float, default=1.2,
                        help="crop side / longest box side (Q-Net's context)")
    parser.add_argument('--box-sigma', type=float, default=0.06,
                        help='box jitter: per-side error / box size')


def _augment_option(parser):
    parser.add_argument('--augment', choices=AUGMENT_STYLES, default='basic',
                        help="photometric augmentation of the training batches: 'basic' "
                             "(brightness, contrast, colour gains, noise) or 'strong' (also "
                             'blur, sharpening, saturation, grey, JPEG, as CosyPose and '
                             'GDR-Net train; default %(default)s)')


def _detector_options(parser):
    _backbone_options(parser)
    _init_option(parser)
    _augment_option(parser)
    parser.add_argument('--train-crop', type=_int_tuple, default=None, metavar='W,H',
                        help='training window in input pixels, multiples of 16 '
                             '(default 192,160)')
    parser.add_argument('--export-input-size', type=_int_tuple, default=None, metavar='W,H',
                        help='input size recorded in the --export copy, multiples of 16: the '
                             'detector is fully convolutional and may run at another size '
                             "than the cache's (default: the cache's)")


def _init_option(parser):
    parser.add_argument('--init', type=Path, default=None, metavar='WEIGHTS',
                        help='start from this weight file of the same kind, objects and '
                             'architecture instead of ImageNet: fine-tuning')


def _backbone_options(parser):
    parser.add_argument('--backbone', choices=BACKBONES, default='scratch',
                        help="'lite0': EfficientNet-Lite0 from ImageNet with a small head; "
                             "'scratch': the plain conv stack (default %(default)s)")
    parser.add_argument('--trunk-lr-scale', type=float, default=None,
                        help="the 'lite0' trunk's learning rate / the head's (0 freezes it; "
                             'default 0.1)')


def _backgrounds_option(parser):
    parser.add_argument('--backgrounds', type=Path, nargs='+', default=None, metavar='DIR',
                        help='folders of photographs used as backgrounds 70%% of the time '
                             '(default: procedural backgrounds only)')


def _table_options(parser):
    """Add the table style's mesh colour ranges, ``--no-shadows`` and ``--no-clutter``."""
    defaults = TableConfig()
    parser.add_argument('--mesh-brightness-range', type=float_pair, metavar='LOW,HIGH',
                        default=None,
                        help="'table' style: per mesh, a brightness gain drawn log-uniformly "
                             'from this range (default %g,%g: no brightness drawn)'
                             % defaults.brightness_range)
    parser.add_argument('--mesh-color-gain-range', type=float_pair, metavar='LOW,HIGH',
                        default=None,
                        help="'table' style: per mesh, per-channel colour gains drawn from "
                             'this range (default %g,%g)' % defaults.color_gain_range)
    parser.add_argument('--no-shadows', action='store_true',
                        help="'table' style: the lights cast no shadows (the same scenes "
                             'otherwise: for measuring what shadows are worth)')
    parser.add_argument('--no-clutter', action='store_true',
                        help="'table' style: the clutter is drawn, then left out of the "
                             'image (the same scenes otherwise: for measuring what clutter '
                             'is worth)')


def _table_config(args):
    """Return the TableConfig of the table-style render options."""
    given = {'brightness_range': args.mesh_brightness_range,
             'color_gain_range': args.mesh_color_gain_range,
             'shadows': False if args.no_shadows else None,
             'clutter': False if args.no_clutter else None}
    return with_inplane_range(
        TableConfig(**{name: value for name, value in given.items() if value is not None}),
        args)


def _refuse_table_options(args):
    """Raise InputError where the table style's options come with another style."""
    given = [option for option, value in (
        ('--mesh-brightness-range', args.mesh_brightness_range),
        ('--mesh-color-gain-range', args.mesh_color_gain_range),
        ('--no-shadows', args.no_shadows or None),
        ('--no-clutter', args.no_clutter or None)) if value is not None]
    if given:
        raise InputError(f'{", ".join(given)}: for --scene-style table, not '
                         f'{args.scene_style}')


def _init(args, kind, objects):
    """Load the trained network of ``--init`` (checked: kind, objects), or return None."""
    if args.init is None:
        return None
    from bbpose_ros.core.inference.weights import load_network
    return load_network(args.init, kind, list(objects))


def _other_models(args, models):
    """{name: ObjectModel} the dataset's meshes that are not targets: table-top clutter."""
    from bbpose_ros.core.data.models import load_bop_models
    return {name: model for name, model in load_bop_models(args.dataset).items()
            if name not in models}


def _photos(args):
    from bbpose_ros.core.synth.backgrounds import PhotoBackgrounds
    return None if not args.backgrounds else PhotoBackgrounds.from_folders(args.backgrounds)


def _common(parser):
    add_dataset_argument(parser)
    add_objects_argument(parser)
    parser.add_argument('--cache', type=Path, default=DEFAULT_CACHE,
                        help='training cache folder (default: $BBPOSE_CACHE or %(default)s)')
    parser.add_argument('--seed', type=int, default=1, help='random seed')
    parser.add_argument('--threads', type=int, default=2, help='torch threads')


def _budget(parser, steps=20000):
    parser.add_argument('--run-dir', type=Path, required=True,
                        help='run folder: checkpoint (resumed), logs, plot, weights')
    parser.add_argument('--steps', type=int, default=steps,
                        help='total steps (the learning-rate schedule spans them)')
    parser.add_argument('--minutes', type=float, default=None,
                        help='stop after this many minutes (resume later)')
    parser.add_argument('--every', type=int, default=500, help='steps between checkpoints')
    parser.add_argument('--export', type=Path, default=None,
                        help='also copy the weight file here at every checkpoint')
    parser.add_argument('--batch', type=int, default=None, help='batch size')
    parser.add_argument('--lr', type=float, default=None, help='peak learning rate')
    parser.add_argument('--max-shards', type=int, default=None,
                        help='use only the first N cache shards')
    parser.add_argument('--device', choices=DEVICES, default=None,
                        help='train on the CPU or a CUDA GPU (automatic mixed precision); '
                             'default: cuda when torch sees a GPU, else cpu')


def _qnet_options(parser):
    parser.add_argument('--crop-size', type=int, default=48, help='crop side (paper: 48)')
    parser.add_argument('--rotation-target', choices=('egocentric', 'allocentric'),
                        default='egocentric', help='regressed rotation (paper: egocentric)')
    parser.add_argument('--sharing', choices=('shared', 'per_object'), default='shared',
                        help='one trunk with per-object heads, or one network per object')
    parser.add_argument('--box-sigma', type=float, default=None,
                        help='crop jitter: per-side box error / box size (default 0.05)')
    parser.add_argument('--box-sigma-from', type=Path, default=None,
                        help='a detector weight file: use its measured side_sigma')
    parser.add_argument('--sign-invariant', action='store_true',
                        help='loss (1 - |q.q_gt|) / 2 instead of the hemisphere rule alone')
    parser.add_argument('--channels', type=_int_tuple, default=QNET_CHANNELS,
                        help='widths of the conv + max-pool stages, comma separated '
                             '(default %(default)s)')
    parser.add_argument('--first-stride', type=int, choices=(1, 2), default=1,
                        help='stride of the first convolution: 1 (paper), or 2 in place of '
                             'the first max-pool (default 1)')
    parser.add_argument('--hypotheses', type=int, default=1,
                        help='quaternions per head, trained winner-takes-all, the best-scored '
                             'one is the output (paper: 1)')
    parser.add_argument('--max-inplane-deg', type=float, default=None,
                        help='train only on crops rolled at most this much about the optical '
                             'axis (an upright-object prior; default: all)')
    _extra_cache_option(parser, 'crop')
    _backbone_options(parser)
    _augment_option(parser)
    parser.add_argument('--real-val', action='store_true',
                        help="also validate on the dataset's real frames with ground-truth "
                             'boxes (measured only, never trained on)')


def _dense_options(parser):
    parser.add_argument('--crop-size', type=int, default=64,
                        help='input crop side, a multiple of 16; the maps are half of it '
                             '(default %(default)s)')
    parser.add_argument('--channels', type=int, default=64,
                        help="the decoder's width at stride 4 (default %(default)s)")
    parser.add_argument('--coordinate-weight', type=float, default=None,
                        help='weight of the coordinate L1 beside the mask BCEs (default 1)')
    parser.add_argument('--frozen-blocks', type=int, default=None,
                        help="trunk blocks (after the stem) kept at ImageNet's weights "
                             '(default 5: strides 2 to 8)')
    _extra_cache_option(parser, 'crop')
    parser.add_argument('--trunk-lr-scale', type=float, default=None,
                        help="the trunk's learning rate / the decoder's (0 freezes it; "
                             'default 0.1)')
    _init_option(parser)
    _augment_option(parser)
    parser.add_argument('--real-val', action='store_true',
                        help="also score the real frames of --dataset's test split at every "
                             'checkpoint (ground-truth boxes, PnP poses, mask IoU); they are '
                             'never trained on')


def _verifier_options(parser):
    parser.add_argument('--detector-weights', type=Path, required=True,
                        help='the trained detector whose candidates are re-scored (its '
                             'first stage is kept, a second stage in it is replaced)')
    parser.add_argument('--channels', type=_int_tuple, default=VERIFIER_CHANNELS,
                        help='widths of the four conv stages (default %(default)s)')
    parser.add_argument('--crop-size', type=int, default=32,
                        help='crop side, a multiple of 8 (default %(default)s)')
    parser.add_argument('--context', type=float, default=1.2,
                        help='crop side / longest box side (default %(default)s)')
    parser.add_argument('--candidates', type=int, default=3,
                        help='peaks per class re-scored at run time (default %(default)s)')
    _extra_cache_option(parser, 'scene')
    parser.add_argument('--real-val', action='store_true',
                        help="also measure the detector's recall on the dataset's real frames "
                             '(measured only, never trained on)')


def _extra_cache_option(parser, kind):
    parser.add_argument('--extra-cache', type=Path, nargs='+', default=(), metavar='DIR',
                        help=f'more {kind} caches to train on, with the same objects, camera '
                             f'and sizes as --cache')


def _settings(settings, args):
    if getattr(args, 'trunk_lr_scale', None) is not None and args.trunk_lr_scale < 0:
        raise InputError(f'--trunk-lr-scale must be >= 0 (0 freezes the trunk), '
                         f'got {args.trunk_lr_scale}')
    if getattr(args, 'augment', None) is not None:
        settings.augment_style = args.augment
    for name in ('batch', 'lr', 'trunk_lr_scale', 'train_crop', 'coordinate_weight',
                 'frozen_blocks'):
        if getattr(args, name, None) is not None:
            setattr(settings, name, getattr(args, name))
    return settings


def _load(args):
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


def _check_input_size(args):
    if len(args.input_size) != 2 or any(side <= 0 or side % 16 for side in args.input_size):
        raise InputError(f'--input-size must be W,H in positive multiples of 16, '
                         f'got {args.input_size}')


def _cache_camera(dataset_dir):
    """
    Return the camera of a dataset's caches: its first test frame's, else camera.json's.

    Rendered and imported caches of one dataset get the same camera, so they mix.
    """
    from bbpose_ros.cli.synth import load_camera
    from bbpose_ros.core.data.bop import BopDataset
    if not Path(dataset_dir).is_dir():
        raise InputError(f'dataset folder not found: {dataset_dir}')
    if not (Path(dataset_dir) / 'test').is_dir():
        return load_camera(dataset_dir)
    frames = BopDataset(dataset_dir).frames()
    return frames[0].camera if frames else load_camera(dataset_dir)


def _evaluation_images(args):
    """
    Images no cache may import: the test frames of ``--dataset`` and of the default dataset.

    They are what ``--real-val``, ``bbpose eval`` and ``replay-eval`` score.
    """
    from bbpose_ros.core.data.bop import BopDataset
    default = Path(os.environ.get('BBPOSE_DATASET', DEFAULT_DATASET))
    paths = []
    for root in {Path(args.dataset).resolve(), default.resolve()}:
        if (root / 'test').is_dir() and (root / 'camera.json').is_file():
            paths += [frame.image_path for frame in BopDataset(root).frames()]
    return paths


def run_render(args):
    """Render the training cache."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.synth import SynthConfig, SyntheticScenes
    from bbpose_ros.core.training.cache import build_cache
    _check_input_size(args)
    camera = _cache_camera(args.dataset)
    models = load_bop_models(args.dataset, args.objects)
    if args.scene_style == 'table':
        from bbpose_ros.core.synth.table_scenes import TableScenes
        scenes = TableScenes(models, camera, seed=args.seed, config=_table_config(args),
                             distractor_models=_other_models(args, models),
                             backgrounds=_photos(args))
    else:
        _refuse_table_options(args)
        scenes = SyntheticScenes(models, camera, seed=args.seed,
                                 config=with_inplane_range(SynthConfig(), args),
                                 backgrounds=_photos(args))
    build_cache(scenes, args.cache, args.scenes, args.input_size, workers=args.workers)
    return 0


def run_render_crops(args):
    """Render the Q-Net crop cache."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.training.crop_cache import build_crop_cache
    camera = _cache_camera(args.dataset)
    models = load_bop_models(args.dataset, args.objects)
    if args.scene_style == 'table':
        from bbpose_ros.core.synth.table_crops import TableCrops
        if args.scenes is None or args.scenes < 1:
            raise InputError('--scene-style table needs --scenes N (N >= 1): the table scenes '
                             'to render')
        scenes = TableCrops(models, camera, seed=args.seed,
                            config=_table_config(args),
                            distractor_models=_other_models(args, models),
                            backgrounds=_photos(args), crop_size=args.crop_size,
                            context=args.context, box_sigma=args.box_sigma,
                            dense_size=args.dense_size)
        count = args.scenes
    else:
        from bbpose_ros.core.synth.crop_scenes import CROP_SYNTH_CONFIG, CropScenes
        if args.scenes is not None:
            raise InputError("--scenes is for --scene-style table; 'random' counts --crops")
        _refuse_table_options(args)
        scenes = CropScenes(models, camera, seed=args.seed,
                            config=with_inplane_range(CROP_SYNTH_CONFIG, args),
                            crop_size=args.crop_size, context=args.context,
                            box_sigma=args.box_sigma, backgrounds=_photos(args),
                            dense_size=args.dense_size)
        count = args.crops
    build_crop_cache(scenes, args.cache, count, workers=args.workers)
    return 0


def run_import_bop(args):
    """Fill a scene or crop cache from the annotated images of a BOP split."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.training.bop_import import (BopImages, import_crop_cache,
                                                     import_scene_cache)
    if args.kind == 'scenes':
        _check_input_size(args)
    elif args.crop_size < 8 or args.context <= 0 or args.box_sigma < 0:
        raise InputError(f'--crop-size must be at least 8, --context positive and --box-sigma '
                         f'non-negative, got {args.crop_size}, {args.context}, '
                         f'{args.box_sigma}')
    if args.workers < 1:
        raise InputError(f'--workers must be at least 1, got {args.workers}')
    images = BopImages(args.images, args.split, _evaluation_images(args))
    camera = _cache_camera(args.dataset)
    models = load_bop_models(args.dataset, args.objects)
    if args.kind == 'scenes':
        count = import_scene_cache(images, args.cache, camera, models, args.input_size,
                                   workers=args.workers)
    else:
        count = import_crop_cache(images, args.cache, camera, models, args.crop_size,
                                  args.context, args.box_sigma, seed=args.seed,
                                  workers=args.workers)
    print(f'{args.cache}: {count} {"scenes" if args.kind == "scenes" else "crops"} from '
          f'{len(images.frames)} images of {args.images} split {args.split}')
    return 0


def run_detector(args):
    """Train the detector."""
    from bbpose_ros.core.nets.detector import DetectorConfig
    from bbpose_ros.core.training.detector_training import DetectorTrainSettings
    from bbpose_ros.core.training.runs import train_detector
    device = training_device(args.device)
    cache, models = _load(args)
    config = DetectorConfig(tuple(models), input_size=tuple(cache.input_size),
                            backbone=args.backbone)
    settings = _settings(DetectorTrainSettings(), args)
    if args.train_crop is None:      # the default window, cut to a smaller cache's frames
        settings.train_crop = tuple(min(side, full) for side, full
                                    in zip(settings.train_crop, cache.input_size))
    window = settings.train_crop
    if len(window) != 2 or any(side <= 0 or side % 16 or side > full
                               for side, full in zip(window, cache.input_size)):
        raise InputError(f'--train-crop must be W,H in multiples of 16 within the cache input '
                         f'size {tuple(cache.input_size)}, got {tuple(window)}')
    export_size = args.export_input_size
    if export_size is not None and (args.export is None or any(
            side <= 0 or side % 16 for side in export_size)):
        raise InputError('--export-input-size needs --export and W,H in multiples of 16, got '
                         f'{export_size}')
    train_detector(cache, config, settings, args.run_dir,
                   args.steps, _seconds(args), args.seed, args.threads, args.export,
                   args.every, device=device,
                   export_input_size=None if export_size is None else tuple(export_size),
                   init=_init(args, 'detector', models))
    return 0


def run_verifier(args):
    """Train the detector's second stage."""
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training.runs import train_verifier, with_verifier
    from bbpose_ros.core.training.verifier_training import VerifierTrainSettings
    from bbpose_ros.core.inference.weights import load_network
    if args.candidates < 1:
        raise InputError(f'--candidates must be at least 1, got {args.candidates}')
    if args.crop_size < 8 or args.crop_size % 8:
        raise InputError(f'--crop-size must be a positive multiple of 8, got {args.crop_size}')
    if len(args.channels) != 4:
        raise InputError(f'--channels needs 4 widths, got {len(args.channels)}')
    device = training_device(args.device)
    detector = load_network(args.detector_weights, 'detector')
    cache = TrainingCache([args.cache, *args.extra_cache], args.max_shards)
    if tuple(cache.input_size) != tuple(detector.config.input_size):
        raise InputError(f'training cache {args.cache}: input size {cache.input_size} is not '
                         f"the detector's {detector.config.input_size}")
    cascade = with_verifier(detector, args.channels, args.crop_size, args.context,
                            args.candidates)
    real = None
    if args.real_val:
        from bbpose_ros.core.data.bop import BopDataset
        from bbpose_ros.core.training.real_validation import RealDetections
        real = RealDetections(BopDataset(args.dataset).frames(), cascade.config.objects)
    train_verifier(cache, cascade, _settings(VerifierTrainSettings(), args), args.run_dir,
                   args.steps, _seconds(args), args.seed, args.threads, args.export,
                   args.every, real_frames=real, device=device)
    return 0


def _qnet_setup(args):
    from bbpose_ros.core.nets.qnet import QNetConfig
    from bbpose_ros.core.training.qnet_training import QNetTrainSettings
    if args.hypotheses < 1:
        raise InputError(f'--hypotheses must be at least 1, got {args.hypotheses}')
    device = training_device(args.device)
    cache, models = _load(args)
    try:
        config = QNetConfig(tuple(models), crop_size=args.crop_size, channels=args.channels,
                            first_stride=args.first_stride,
                            rotation_target=args.rotation_target, sharing=args.sharing,
                            hypotheses=args.hypotheses, backbone=args.backbone)
    except ValueError as err:
        raise InputError(f'invalid Q-Net options: {err}') from None
    settings = _settings(QNetTrainSettings(sign_invariant=args.sign_invariant,
                                           max_inplane_deg=args.max_inplane_deg), args)
    if args.box_sigma_from is not None:
        settings.box_sigma = _measured_sigma(args.box_sigma_from)
    if args.box_sigma is not None:
        settings.box_sigma = args.box_sigma
    return cache, models, config, settings, device


def run_qnet(args):
    """Train Q-Net."""
    from bbpose_ros.core.training.runs import train_qnet
    cache, models, config, settings, device = _qnet_setup(args)
    real = None
    if args.real_val:
        from bbpose_ros.core.data.bop import BopDataset
        from bbpose_ros.core.training.real_validation import RealCrops
        real = RealCrops(BopDataset(args.dataset).frames(), config.objects, models)
    train_qnet(cache, models, config, settings, args.run_dir, args.steps, _seconds(args),
               args.seed, args.threads, args.export, args.every, real_crops=real,
               device=device, init=_init(args, 'qnet', models))
    return 0


def run_dense(args):
    """Train the dense correspondence net."""
    from bbpose_ros.core.data.models import load_bop_models
    from bbpose_ros.core.nets.dense import DenseConfig
    from bbpose_ros.core.training.crop_cache import CropCache
    from bbpose_ros.core.training.dense_training import DenseTrainSettings
    from bbpose_ros.core.training.runs import train_dense
    device = training_device(args.device)
    cache = CropCache([args.cache, *args.extra_cache], args.max_shards)
    models = load_bop_models(args.dataset, args.objects or cache.objects)
    try:
        config = DenseConfig(tuple(models), crop_size=args.crop_size, context=cache.context,
                             channels=args.channels)
    except ValueError as err:
        raise InputError(f'invalid dense net options: {err}') from None
    settings = _settings(DenseTrainSettings(), args)
    real = None
    if args.real_val:
        from bbpose_ros.core.data.bop import BopDataset
        from bbpose_ros.core.training.real_validation import RealDenseCrops
        real = RealDenseCrops(BopDataset(args.dataset).frames(), config,
                              load_bop_models(args.dataset))
    train_dense(cache, models, config, settings, args.run_dir, args.steps, _seconds(args),
                args.seed, args.threads, args.export, args.every, real_crops=real,
                device=device, init=_init(args, 'dense', models))
    return 0


def run_quantize(args):
    """Write the int8 graph of the detector or Q-Net, calibrated on a scene cache."""
    import shlex
    import sys

    from bbpose_ros.core.inference.int8_graphs import int8_graph_path
    from bbpose_ros.core.inference.weights import (DEFAULT_DETECTOR_WEIGHTS,
                                                   DEFAULT_QNET_WEIGHTS, load_network)
    from bbpose_ros.core.training.cache import TrainingCache
    from bbpose_ros.core.training import quantization
    count = args.inputs or (32 if args.network == 'detector' else 256)
    if count < 1:
        raise InputError(f'--inputs must be at least 1, got {count}')
    default = DEFAULT_DETECTOR_WEIGHTS if args.network == 'detector' else DEFAULT_QNET_WEIGHTS
    weights = args.weights or default
    config = load_network(weights, args.network).config
    cache = TrainingCache(args.cache, max_shards=1)
    if args.network == 'detector':
        inputs = (quantization.calibration_images(cache.images, config.input_size, count),)
    else:
        inputs = quantization.calibration_crops(cache, config, count)
    out = quantization.quantize_network(weights, args.network, inputs,
                                        args.out or int8_graph_path(weights),
                                        command=shlex.join(['bbpose', *sys.argv[1:]]))
    print(f'int8 {args.network} graph written to {out} ({out.stat().st_size / 1e6:.2f} MB, '
          f'{len(inputs[0])} calibration inputs from {args.cache})')
    return 0


def run_fig3(args):
    """Train Q-Net with and without q-normalization and plot both losses."""
    from bbpose_ros.core.training.fig3 import q_normalization_experiment
    cache, models, config, settings, device = _qnet_setup(args)
    summary = q_normalization_experiment(cache, models, config, settings, args.run_dir,
                                         args.steps, args.seed, args.threads, device=device)
    print(json.dumps(summary, indent=1))
    return 0


def _int_tuple(text):
    try:
        return tuple(int(x) for x in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated integers, got {text!r}')


def _seconds(args):
    return None if args.minutes is None else args.minutes * 60.0


def _measured_sigma(path):
    from bbpose_ros.core.inference.weights import read_weights
    metadata, _ = read_weights(path, 'detector')
    sigma = metadata.get('training', {}).get('validation', {}).get('side_sigma')
    if not sigma:
        raise InputError(f'weight file {path}: field "training.validation.side_sigma" is '
                         'missing')
    return float(sigma)
