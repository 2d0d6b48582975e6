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
One new object, from its checked mesh to weight files the node loads (``bbpose add-object``).

Stages, each written whole into the output folder, so that a run that stops resumes at the
first stage whose output is missing (the renders resume shard by shard):

1. ``dataset/``: a BOP dataset of the known objects' meshes and the new one (``camera.json``,
   ``models/`` with ``models_info.json`` and the names table) for the node and the renders.
2. ``renders/scenes``: table-top scenes at the detector's input size with the new object
   among the known ones and clutter (only the new object labelled); ``renders/crops``:
   crops around the new object alone at the dense net's crop size, with dense targets.
3. ``detector.pt``, ``qnet.pt``, ``dense.pt``: the base networks with a block of rows for
   the new object, trained on the renders with everything else frozen (``object_rows``).
4. ``detector_int8.onnx``, ``qnet_int8.onnx``: their int8 graphs, calibrated on the renders.
5. ``preview.png`` (rendered scenes with boxes, crops as Q-Net sees them) and
   ``report.json`` (stage times, settings, the figures on the held-out renders).

``pipeline_files`` tells what the node loads from the folder; ``bbpose add-object`` writes it
as the node's parameters, ``params.yaml`` (``ros/params_file.py``).

``inputs.json`` records what the folder was made from; a second run with other inputs is
refused rather than mixing two objects' files.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, replace
from functools import cached_property
import json
from pathlib import Path
import shutil
from typing import Any

import cv2
import numpy as np

from bbpose_ros.core.add_object.add_object_settings import AddedObject, AddObjectSettings
from bbpose_ros.core.data.bop import load_camera
from bbpose_ros.core.data.fingerprints import sha256_of_arrays
from bbpose_ros.core.data.mesh_check import write_bop_model
from bbpose_ros.core.data.models import (load_bop_models, load_models_info, NAMES_FILE,
                                         object_names)
from bbpose_ros.core.inference.int8_graphs import file_sha256, int8_graph_path
from bbpose_ros.core.inference.weights import load_network, save_weights
from bbpose_ros.core.pipeline.loader import PipelineFiles, WeightFiles
from bbpose_ros.core.pipeline.overlays import tile_grid
from bbpose_ros.core.synth.crop_scenes import CROP_SYNTH_CONFIG, CropScenes
from bbpose_ros.core.synth.export import camera_json, draw_preview
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.synth.table_scenes import TableScenes
from bbpose_ros.core.training.cache import build_cache, TrainingCache
from bbpose_ros.core.training.crop_cache import build_crop_cache, CropCache
from bbpose_ros.core.training.object_rows import fit_new_rows, with_objects
from bbpose_ros.core.training.quantization import write_int8_graphs
from bbpose_ros.core.training.runs import git_commit
from bbpose_ros.core.training.settings import (DenseTrainSettings, DetectorTrainSettings,
                                               QNetTrainSettings)
from bbpose_ros.core.training.staged_folder import StagedFolder
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import atomic_output, write_json_atomic, write_rgb_png

NETWORKS = ('detector', 'qnet', 'dense')
# Rolls of the rendered objects about the optical axis, degrees: upright objects seen by a
# roughly upright camera, as the shipped networks were trained.
INPLANE_RANGE_DEG = (-60.0, 60.0)
# Per-side box jitter / box size of the rendered crops (the detector's errors).
CROP_BOX_SIGMA = 0.06
CALIBRATION_FRAMES = 32
# preview.png's rendered scenes, each shrunk to (width, height) pixels.
PREVIEW_TILE = (320, 240)


class AddObject:
    """
    The stages of adding ``new`` to the networks of ``base`` into ``out`` (module docstring).

    Args:
        new: the AddedObject.
        base_weights: {'detector' | 'qnet' | 'dense': weight file} to extend.
        base_dataset: BOP dataset with the meshes of the base networks' objects.
        out: output folder.
        settings: AddObjectSettings.
        backgrounds: PhotoBackgrounds for the renders, or None (procedural textures).
        progress: show tqdm bars.
        log: callable(str) for one line per stage.
        command: the command line, recorded in the report and the weight files.
        keep_renders: keep ``renders/`` when done (by default removed: the networks and
            int8 graphs no longer need it, and it is the folder's bulk).

    """

    def __init__(self, new: AddedObject, base_weights: Mapping[str, Path], base_dataset: Path,
                 out: Path, settings: AddObjectSettings, backgrounds=None,
                 progress: bool = True, log: Callable[[str], None] = print,
                 command: str = '', keep_renders: bool = False) -> None:
        self.keep_renders = keep_renders
        self.new, self.base_weights = new, {k: Path(v) for k, v in base_weights.items()}
        self.base_dataset, self.out = Path(base_dataset), Path(out)
        self.settings, self.backgrounds = settings, backgrounds
        self.progress, self.log, self.command = progress, log, command
        self.base = {kind: load_network(self.base_weights[kind], kind) for kind in NETWORKS}
        self.known = list(self.base['detector'].config.objects)
        for kind in NETWORKS[1:]:
            objects = list(self.base[kind].config.objects)
            if objects != self.known:
                raise InputError(f'{self.base_weights[kind]}: objects {objects} differ from '
                                 f"the detector's {self.known}")
        if new.name in self.known:
            raise InputError(f'the base networks know an object named {new.name!r} already; '
                             'choose another --name')
        self.objects = self.known + [new.name]
        self.report: dict[str, Any] = {}
        self.folder: StagedFolder | None = None

    def run(self) -> dict[str, Any]:
        """Run the stages not yet done; return the report (also in ``report.json``)."""
        self.folder = StagedFolder(self.out, self.log)
        self._check_inputs()
        self.report = self.folder.report
        self.report.update(object=self.new.name, objects=self.objects, command=self.command,
                           settings=asdict(self.settings), git_commit=git_commit())
        stage = self.folder.stage
        stage('dataset', self._dataset, self.out / 'dataset')
        if not (self.out / 'preview.png').exists():       # the renders' last reader
            stage('renders', self._renders, None)
        for kind in NETWORKS:
            stage(kind, lambda kind=kind: self._network(kind), self.out / f'{kind}.pt')
        stage('int8', self._int8, int8_graph_path(self.out / 'qnet.pt'))
        stage('preview', self._preview, self.out / 'preview.png')
        if not self.keep_renders and (self.out / 'renders').exists():
            size = _folder_bytes(self.out / 'renders')
            shutil.rmtree(self.out / 'renders')
            self.log(f'[renders] removed ({size / 2 ** 20:.0f} MB; --keep-renders keeps them)')
        self.report['disk_mb'] = round(_folder_bytes(self.out) / 2 ** 20, 1)
        return self.folder.finish()

    def _check_inputs(self):
        """Record the inputs, or refuse a folder made from others (``StagedFolder``)."""
        self.folder.check_inputs({
            'name': self.new.name, 'mesh_sha256': sha256_of_arrays(
                self.new.mesh.vertices, self.new.mesh.faces, self.new.mesh.colors),
            'symmetries': np.round(self.new.symmetries, 6).tolist(),
            'base_weights': {k: file_sha256(v) for k, v in self.base_weights.items()},
            'base_dataset': str(self.base_dataset.resolve()),
            'settings': asdict(self.settings),
            'backgrounds': 0 if self.backgrounds is None else len(self.backgrounds.paths)})

    def _dataset(self):
        """Write ``dataset/``: camera, the known meshes and the new one, names table."""
        names = object_names(self.base_dataset)
        ids = {name: obj_id for obj_id, name in names.items()}
        missing = [name for name in self.known if name not in ids]
        if missing:
            raise InputError(f'{self.base_dataset}: no mesh for the base objects '
                             f'{", ".join(missing)}')
        info = load_models_info(self.base_dataset / 'models' / 'models_info.json')
        new_id = max(names) + 1
        with atomic_output(self.out / 'dataset') as staging:
            staging.mkdir()
            write_bop_model(self.new.mesh, staging / 'models', new_id, self.new.name)
            models = staging / 'models'
            entry = json.loads((models / 'models_info.json').read_text())[str(new_id)]
            if len(self.new.symmetries):
                entry['symmetries_discrete'] = [m.reshape(-1).tolist()
                                                for m in self.new.symmetries]
            table = {str(new_id): entry}
            for name in self.known:
                obj_id = ids[name]
                shutil.copyfile(self.base_dataset / 'models' / f'obj_{obj_id:06d}.ply',
                                models / f'obj_{obj_id:06d}.ply')
                table[str(obj_id)] = info[obj_id]
            write_json_atomic(models / 'models_info.json',
                              dict(sorted(table.items(), key=lambda kv: int(kv[0]))))
            write_json_atomic(models / NAMES_FILE, {str(i): n for i, n in sorted(
                {**{ids[n]: n for n in self.known}, new_id: self.new.name}.items())})
            write_json_atomic(staging / 'camera.json',
                              camera_json(load_camera(self.base_dataset)))

    @cached_property
    def models(self) -> dict:
        """{name: ObjectModel} of ``dataset/`` (known objects and the new one)."""
        return load_bop_models(self.out / 'dataset', self.objects)

    def _table_scenes(self) -> TableScenes:
        """Return the detector's scene source: the new object labelled, the known ones clutter."""
        return TableScenes({self.new.name: self.models[self.new.name]},
                           load_camera(self.out / 'dataset'), self.settings.seed,
                           TableConfig(inplane_range_deg=INPLANE_RANGE_DEG),
                           distractor_models={n: self.models[n] for n in self.known},
                           backgrounds=self.backgrounds)

    def _renders(self):
        """Render the scene cache and the crop cache (each resumes its missing shards)."""
        settings = self.settings
        dense = self.base['dense'].config
        build_cache(self._table_scenes(), self.out / 'renders' / 'scenes', settings.scenes,
                    self.base['detector'].config.input_size, settings.workers, self.progress,
                    settings.scene_shard)
        crops = CropScenes({self.new.name: self.models[self.new.name]},
                           load_camera(self.out / 'dataset'), seed=settings.seed + 1,
                           config=replace(CROP_SYNTH_CONFIG,
                                          inplane_range_deg=INPLANE_RANGE_DEG),
                           crop_size=dense.crop_size, context=dense.context,
                           box_sigma=CROP_BOX_SIGMA, backgrounds=self.backgrounds,
                           dense_size=dense.map_size)
        build_crop_cache(crops, self.out / 'renders' / 'crops', settings.crops,
                         settings.workers, self.progress, settings.crop_shard)

    def _network(self, kind):
        """Extend the base network by the new object's rows, train them, write the file."""
        settings = self.settings
        network = with_objects(self.base[kind], self.objects)
        if kind == 'detector':
            cache = TrainingCache(self.out / 'renders' / 'scenes')
            train = DetectorTrainSettings(augment='strong', val_fraction=settings.held_out)
        elif kind == 'qnet':
            cache = CropCache(self.out / 'renders' / 'crops')
            train = QNetTrainSettings(augment='strong', sign_invariant=True,
                                      max_inplane_deg=45.0, val_fraction=settings.held_out)
        else:
            cache = CropCache(self.out / 'renders' / 'crops')
            train = DenseTrainSettings(augment='strong', coordinate_weight=3.0,
                                       val_fraction=settings.held_out)
        rows = getattr(settings, kind)
        figures = fit_new_rows(network, [self.new.name], cache, self.models, train, rows,
                               settings.seed, self.progress)
        self.report.setdefault('held_out_renders', {})[kind] = figures
        record = {'command': self.command, 'git_commit': git_commit(),
                  'trained': f'rows of {self.new.name} only (bbpose add-object)',
                  'base': str(self.base_weights[kind]), 'rows': asdict(rows),
                  'settings': asdict(train), 'validation': figures}
        save_weights(self.out / f'{kind}.pt', network, kind, record)
        self.log(f'[{kind}] held-out renders: ' +
                 ', '.join(f'{k} {v:.3f}' for k, v in figures.items()))

    def _int8(self):
        """Write the detector's and Q-Net's int8 graphs, calibrated on the scene renders."""
        write_int8_graphs(self.out, TrainingCache(self.out / 'renders' / 'scenes'),
                          CALIBRATION_FRAMES, self.settings.seed, 'bbpose add-object')

    def _preview(self):
        """Write ``preview.png``: 4 rendered scenes with boxes over 16 crops at Q-Net's size."""
        scenes = self._table_scenes()
        try:
            images = [draw_preview(scenes.sample(k)) for k in range(4)]
        finally:
            scenes.close()
        top = tile_grid(images, len(images), PREVIEW_TILE)
        crops = CropCache(self.out / 'renders' / 'crops')
        size = self.base['qnet'].config.crop_size
        picked = crops.crop[:16]
        small = [cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA) for c in picked]
        side = top.shape[1] // 16
        strip = np.concatenate([cv2.resize(c, (side, side), interpolation=cv2.INTER_NEAREST)
                                for c in small], axis=1)
        strip = np.pad(strip, ((0, 0), (0, top.shape[1] - strip.shape[1]), (0, 0)))
        write_rgb_png(self.out / 'preview.png', np.concatenate([top, strip], axis=0))

    def pipeline_files(self) -> PipelineFiles:
        """Return what the node loads from the output folder (``output_files``)."""
        return output_files(self.out, self.objects)


def output_files(out: Path, objects: Sequence[str]) -> PipelineFiles:
    """
    Return the objects, dataset folder and weight files of an add-object folder ``out``.

    Every other node parameter keeps its default (config/bbpose.yaml).
    """
    out = Path(out)
    return PipelineFiles(tuple(objects), out / 'dataset',
                         WeightFiles(*(out / f'{kind}.pt' for kind in NETWORKS)))


def _folder_bytes(folder: Path) -> int:
    """Total size of the files under ``folder``, bytes."""
    return sum(path.stat().st_size for path in folder.rglob('*') if path.is_file())
