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
``bbpose adapt``'s stages: from an unlabelled recording to weight files the node loads.

Each stage is written whole into the output folder, so a run that stops resumes at the
first stage whose output is missing:

1. ``frames.json``: the recording's frame keys and pixel fingerprints (``frames``); a
   second run on another recording or other settings is refused (``inputs.json``).
2. Per round r (``rounds``): ``round<r>/teacher.json``, the careful pipeline's poses of
   every frame (round 1 with the base weights, later rounds with the previous round's);
   ``round<r>/verdicts.json``, the gates' verdicts, keeping a larger share each round;
   ``round<r>/labels/``, the accepted labels as a scene cache; ``round<r>/detector.pt`` and
   ``round<r>/qnet.pt``, the students trained from the base weights on those labels.
3. ``detector.pt``, ``qnet.pt`` (the last round's, recording in their metadata the
   fingerprints of the frames they adapted on: ``bbpose eval`` refuses to score those) and
   their int8 graphs, calibrated on the recording.
4. ``pseudo_labels/``: the last round's accepted labels as a BOP split written as
   ``bbpose synth`` writes one (``synth.export.BopSceneWriter``: images, cameras, poses,
   amodal boxes and the labels' confidences; ``source_frames.json`` names each image's
   frame in the recording), an auto-annotation other tools can train on.
5. ``preview.png`` (accepted labels green, refused ones red with their verdict) and
   ``report.json`` (labels per object and round, student figures, stage times).

``Adaptation.pipeline_files`` tells what the node loads from the folder; ``bbpose adapt``
writes ``params.yaml``, the base parameters with the adapted weight files
(``ros/params_file.py``).
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, replace
import json
from pathlib import Path
import shutil
from typing import Any

import numpy as np
from tqdm import tqdm

from bbpose_ros.core.adaptation.adapt_settings import AdaptSettings
from bbpose_ros.core.adaptation.frames import image_fingerprint, RecordedFrame
from bbpose_ros.core.adaptation.label_set import IgnoreRegions, write_label_set
from bbpose_ros.core.adaptation.map_labels import mapped_teacher_poses
from bbpose_ros.core.adaptation.selection import select_labels, Verdict, verdict_counts
from bbpose_ros.core.adaptation.students import adapt_detector, adapt_qnet
from bbpose_ros.core.adaptation.teacher import Teacher, TeacherPose
from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.inference.int8_graphs import int8_graph_path
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.inference.weights import load_network, read_weights, save_weights
from bbpose_ros.core.pipeline.loader import PipelineFiles, WeightFiles
from bbpose_ros.core.pipeline.overlays import draw_box_2d, draw_label, tile_grid
from bbpose_ros.core.synth.export import BopSceneWriter, write_json
from bbpose_ros.core.training.cache import TrainingCache
from bbpose_ros.core.training.quantization import write_int8_graphs
from bbpose_ros.core.training.runs import git_commit
from bbpose_ros.core.training.staged_folder import StagedFolder
from bbpose_ros.core.util.files import atomic_output, write_json_atomic, write_rgb_png

STUDENTS = ('detector', 'qnet')
# The weight-file metadata field naming the frames a network adapted on.
ADAPTED_ON = 'adapted_on'
PREVIEW_FRAMES = 8
# preview.png: frames in rows of this many, each shrunk to (width, height) pixels.
PREVIEW_COLUMNS, PREVIEW_TILE = 4, (320, 240)
ACCEPTED_COLOR, REFUSED_COLOR = (0, 220, 0), (230, 40, 40)


class Adaptation:
    """
    The stages of adapting ``base`` weights to a recording, into ``out`` (module docstring).

    Args:
        frames: the recording (``frames.dataset_frames`` or ``frames.bag_frames``).
        models: {name: ObjectModel} of the networks' objects.
        options: the node's PipelineOptions (the teacher lays its careful settings over
            them).
        base: the weight files to adapt (concrete paths for detector, qnet and dense).
        out: output folder.
        settings: AdaptSettings.
        progress: show tqdm bars.
        log: callable(str) for one line per stage.
        command: the command line, recorded in the report and the weight files.

    """

    def __init__(self, frames: Sequence[RecordedFrame], models: Mapping[str, ObjectModel],
                 options: PipelineOptions, base: WeightFiles, out: Path,
                 settings: AdaptSettings, progress: bool = True,
                 log: Callable[[str], None] = print, command: str = '') -> None:
        self.frames, self.models = list(frames), dict(models)
        self.options, self.base = options, base
        self.out, self.settings = Path(out), settings
        self.progress, self.log, self.command = progress, log, command
        self.report: dict[str, Any] = {}
        self.folder: StagedFolder | None = None

    def run(self) -> dict[str, Any]:
        """Run the stages not yet done; return the report (also in ``report.json``)."""
        self.folder = StagedFolder(self.out, self.log)
        self.report = self.folder.report
        self.report.update(command=self.command, git_commit=git_commit(),
                           settings=asdict(self.settings), frames=len(self.frames),
                           objects=list(self.models))
        stage = self.folder.stage
        stage('frames', self._fingerprints, self.out / 'frames.json')
        self.folder.check_inputs({
            'frames': self.fingerprints, 'objects': list(self.models),
            'base_weights': {k: str(getattr(self.base, k)) for k in ('detector', 'qnet',
                                                                     'dense')},
            'settings': asdict(self.settings)})
        weights = self.base
        for number in range(1, self.settings.rounds + 1):
            weights = self._round(number, weights)
        stage('export', lambda: self._export(weights), self.out / 'qnet.pt')
        stage('int8', self._int8, int8_graph_path(self.out / 'qnet.pt'))
        stage('pseudo_labels', self._pseudo_labels, self.out / 'pseudo_labels')
        stage('preview', self._preview, self.out / 'preview.png')
        return self.folder.finish()

    def _fingerprints(self):
        """Write ``frames.json``: each frame's key and pixel fingerprint."""
        entries = [{'key': f.key, 'sha256': image_fingerprint(f.read())}
                   for f in tqdm(self.frames, desc='fingerprints', unit='frame',
                                 disable=not self.progress)]
        write_json_atomic(self.out / 'frames.json', entries)

    @property
    def fingerprints(self) -> list[str]:
        """SHA-256 pixel fingerprints of the recording's frames, in order (``frames.json``)."""
        return [e['sha256'] for e in json.loads((self.out / 'frames.json').read_text())]

    def _round(self, number: int, teacher_weights: WeightFiles) -> WeightFiles:
        """Run round ``number`` with the teacher on ``teacher_weights``; its students' files."""
        folder = self.out / f'round{number}'
        stage = self.folder.stage
        stage(f'round{number}_teacher', lambda: self._teach(folder, teacher_weights),
              folder / 'teacher.json')
        stage(f'round{number}_labels', lambda: self._select(folder, number), folder / 'labels')
        for kind in STUDENTS:
            stage(f'round{number}_{kind}', lambda kind=kind: self._student(folder, kind),
                  folder / f'{kind}.pt')
        return replace(self.base, detector=folder / 'detector.pt', qnet=folder / 'qnet.pt')

    def _teach(self, folder, weights):
        """
        Write ``teacher.json``: the careful pipeline's poses of every frame.

        With ``map_labels``, where frames carry camera poses, the poses are the map's of
        their scene (``map_labels.py``).
        """
        teacher = Teacher(self.models, self.options, weights, self.settings.teacher_threshold)
        poses = {}
        for frame in tqdm(self.frames, desc='teacher', unit='frame',
                          disable=not self.progress):
            poses[frame.key] = teacher(frame.read(), frame.camera)
        if self.settings.map_labels and any(frame.world_from_camera is not None
                                            for frame in self.frames):
            poses, moved = mapped_teacher_poses(self.frames, poses, self.models, self.options)
            self.log(f'[teacher] the map of each scene gave {moved} of '
                     f'{sum(len(p) for p in poses.values())} poses (frames with camera poses)')
            self.report.setdefault('teacher_map', {})[folder.name] = moved
        write_json_atomic(folder / 'teacher.json',
                          {key: [p.record() for p in found] for key, found in poses.items()})

    def verdicts(self, number: int) -> dict[str, list[Verdict]]:
        """{frame key: [Verdict]} of round ``number``, as ``_select`` gave them."""
        return read_round(self.out / f'round{number}')

    def _select(self, folder, number):
        """Judge the teacher's poses; write ``verdicts.json`` and the label set."""
        poses = json.loads((folder / 'teacher.json').read_text())
        verdicts = select_labels({key: [TeacherPose.from_record(r) for r in records]
                                  for key, records in poses.items()},
                                 self.settings.selection_of(number))
        counts = verdict_counts(verdicts)
        self.report.setdefault('labels', {})[f'round{number}'] = counts
        accepted = sum(c['accepted'] for c in counts.values())
        self.log(f'[round{number}] {accepted} labels accepted of '
                 f'{sum(sum(c.values()) for c in counts.values())} poses: ' +
                 ', '.join(f'{name} {c["accepted"]}' for name, c in counts.items()))
        write_json_atomic(folder / 'verdicts.json', {
            key: [{'object': v.pose.object_name, 'verdict': v.verdict} for v in judged]
            for key, judged in verdicts.items()})
        metadata, _ = read_weights(self.base.detector, 'detector')
        write_label_set(folder / 'labels', self.frames, verdicts, list(self.models),
                        metadata['input_size'])

    def _student(self, folder, kind):
        """Train one student from the base weights on the round's labels; write its file."""
        cache = TrainingCache(folder / 'labels')
        base = getattr(self.base, kind)
        network = load_network(base, kind, list(self.models))
        if kind == 'detector':
            figures = adapt_detector(network, cache, IgnoreRegions.read(folder / 'labels'),
                                     self.settings.detector, self.settings.seed,
                                     self.progress)
            training = asdict(self.settings.detector)
        else:
            figures = adapt_qnet(network, cache, self.models, self.settings.qnet,
                                 self.settings.seed, self.progress)
            training = asdict(self.settings.qnet)
        self.report.setdefault('students', {})[f'{folder.name}_{kind}'] = figures
        self.log(f'[{folder.name} {kind}] ' +
                 ', '.join(f'{k} {v:.4f}' for k, v in figures.items()))
        metadata, _ = read_weights(base, kind)
        record = {'command': self.command, 'git_commit': git_commit(),
                  'trained': 'adapted to a recording by bbpose adapt (heads only)',
                  'base': str(base), 'base_training': metadata.get('training', {}),
                  'settings': training, 'labels': len(cache.object),
                  ADAPTED_ON: self.fingerprints}
        save_weights(folder / f'{kind}.pt', network, kind, record)

    def _export(self, weights):
        """Copy the last round's students to the output folder."""
        shutil.copyfile(weights.detector, self.out / 'detector.pt')
        shutil.copyfile(weights.qnet, self.out / 'qnet.pt')

    def _int8(self):
        """Write both students' int8 graphs, calibrated on the last round's label set."""
        cache = TrainingCache(self.out / f'round{self.settings.rounds}' / 'labels')
        write_int8_graphs(self.out, cache, len(cache.images), self.settings.seed,
                          'bbpose adapt')

    def _pseudo_labels(self):
        """Write the last round's accepted labels as a BOP dataset folder."""
        verdicts = self.verdicts(self.settings.rounds)
        ids = {name: model.obj_id for name, model in self.models.items()}
        with atomic_output(self.out / 'pseudo_labels') as staging:
            writer = BopSceneWriter(staging, self.frames[0].camera, ids, split='test')
            sources = {}
            for image_id, frame in enumerate(self.frames):
                labels = [v.pose for v in verdicts.get(frame.key, []) if v.accepted]
                if labels:
                    writer.add_poses(image_id, frame.read(), frame.camera, labels,
                                     [{'visib_fract': 1.0, 'confidence': p.confidence}
                                      for p in labels])
                    sources[str(image_id)] = frame.key
            writer.finish()
            write_json(writer.scene_dir / 'source_frames.json', sources)

    def _preview(self):
        """Write ``preview.png``: frames with accepted (green) and refused (red) labels."""
        number = self.settings.rounds
        verdicts = self.verdicts(number)
        picks = np.linspace(0, len(self.frames) - 1, min(PREVIEW_FRAMES, len(self.frames)))
        tiles = []
        for index in np.unique(picks.astype(int)):
            frame = self.frames[index]
            image = frame.read().copy()
            for verdict in verdicts.get(frame.key, []):
                color = ACCEPTED_COLOR if verdict.accepted else REFUSED_COLOR
                text = verdict.pose.object_name + ('' if verdict.accepted
                                                   else f' ({verdict.verdict})')
                draw_box_2d(image, verdict.pose.box_uv, color, 2)
                draw_label(image, text, verdict.pose.box_uv, color)
            tiles.append(image)
        write_rgb_png(self.out / 'preview.png', tile_grid(tiles, PREVIEW_COLUMNS, PREVIEW_TILE))

    def pipeline_files(self) -> PipelineFiles:
        """Return what the node loads from the output folder: the adapted weight files."""
        return PipelineFiles(tuple(self.models), weights=WeightFiles(
            detector=self.out / 'detector.pt', qnet=self.out / 'qnet.pt'))


def read_round(folder: Path | str) -> dict[str, list[Verdict]]:
    """{frame key: [Verdict]} of one round folder (its ``teacher.json`` and ``verdicts.json``)."""
    folder = Path(folder)
    poses = json.loads((folder / 'teacher.json').read_text())
    verdicts = json.loads((folder / 'verdicts.json').read_text())
    return {key: [Verdict(TeacherPose.from_record(p), v['verdict'])
                  for p, v in zip(poses[key], judged)] for key, judged in verdicts.items()}


def read_rounds(out: Path | str) -> dict[str, dict[str, list[Verdict]]]:
    """{'round<r>': {frame key: [Verdict]}} of an output folder's finished selections."""
    return {folder.name: read_round(folder) for folder in sorted(Path(out).glob('round[0-9]'))
            if (folder / 'verdicts.json').is_file()}


def adapted_frames(weights: Path | str, kind: str) -> set[str]:
    """Return the fingerprints of the frames a weight file adapted on (empty: none)."""
    metadata, _ = read_weights(weights, kind)
    return set(metadata.get('training', {}).get(ADAPTED_ON, []))
