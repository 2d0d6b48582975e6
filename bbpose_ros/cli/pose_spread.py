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
Measure the per-object pose spread the node reports as Detection3D covariance.

    python -m bbpose_ros.cli.pose_spread [--dataset DIR] [--out FILE]

Runs the shipped pipeline with the node's default settings (detector boxes, Q-Net,
refinement) over every frame of a BOP dataset (default: the LM-O development frames,
$BBPOSE_DATASET or ../shared/datasets/lmo) and compares each pose with the ground-truth
instance it localises: the nearest instance of its object in 3D, within one object diameter
(farther poses are wrong detections and are left out). Per object it writes, to
``bbpose_ros/weights/pose_spread.json``:

* ``sigma_m``: the spread of the translation error along the camera's x, y, z axes, metres;
* ``sigma_rad``: the spread of the rotation error (the rotation vector of R_est R_gt^T, in
  the camera frame, against the nearest symmetric equivalent of the truth) about x, y, z;
* ``confidence_median``: the median confidence of those poses;
* ``n``: how many poses were measured.

A spread is 1.4826 x the median absolute error, the standard deviation a normal error would
have, robust to the few flips a symmetric-looking view causes. The node scales it by
``confidence_median / confidence`` (``ros.detections.PoseSpread``).
"""

import argparse
from collections.abc import Mapping, Sequence
from datetime import date
import json
import os
from pathlib import Path
import sys

import cv2
import numpy as np

from bbpose_ros.core.data.bop import BopDataset, DEFAULT_DATASET, GroundTruthInstance
from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.eval.metrics import symmetric_ground_truths
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.pipeline.loader import load_pipeline
from bbpose_ros.core.pipeline.poses import PoseEstimate

OUT = Path(__file__).resolve().parents[1] / 'weights' / 'pose_spread.json'
MAD_TO_SIGMA = 1.4826


def rotation_vector(rotation: np.ndarray) -> np.ndarray:
    """(3,) axis x angle (radians) of a (3, 3) rotation."""
    vector, _ = cv2.Rodrigues(np.asarray(rotation, dtype=np.float64))
    return vector.reshape(3)


def pose_errors(pose: PoseEstimate, truths: Sequence[GroundTruthInstance],
                models: Mapping[str, ObjectModel]) -> tuple[np.ndarray, np.ndarray] | None:
    """
    Return (translation error (3,) m, rotation error (3,) rad) of a pose, or None.

    The truth is the nearest instance of the pose's object within one diameter; its
    symmetric equivalent nearest in rotation is the reference.
    """
    model = models[pose.object_name]
    same = [t for t in truths if t.object_name == pose.object_name]
    if not same:
        return None
    truth = min(same, key=lambda t: np.linalg.norm(t.translation - pose.translation))
    if np.linalg.norm(truth.translation - pose.translation) > model.diameter:
        return None
    rotations, translations = symmetric_ground_truths(truth.rotation, truth.translation,
                                                      model.symmetry_transforms)
    vectors = [rotation_vector(pose.rotation @ r.T) for r in rotations]
    best = int(np.argmin([np.linalg.norm(v) for v in vectors]))
    return pose.translation - translations[best], vectors[best]


def measure(dataset: Path) -> dict:
    """Return the pose_spread.json content of the pipeline's poses on ``dataset``."""
    bop = BopDataset(dataset)
    models = bop.load_models()
    pipeline = load_pipeline(models, PipelineOptions())
    errors = {name: [] for name in models}
    frames = bop.frames()
    for k, frame in enumerate(frames):
        poses = pipeline.estimate(frame.load_image(), frame.camera).poses
        for pose in poses:
            found = pose_errors(pose, frame.instances, models)
            if found is not None:
                errors[pose.object_name].append((*found, pose.confidence))
        print(f'frame {k + 1}/{len(frames)}: {len(poses)} poses', file=sys.stderr)
    objects = {}
    for name, rows in errors.items():
        if not rows:
            continue
        t_err = np.array([r[0] for r in rows])
        r_err = np.array([r[1] for r in rows])
        objects[name] = {
            'sigma_m': [round(float(v), 5) for v in MAD_TO_SIGMA * np.median(abs(t_err), 0)],
            'sigma_rad': [round(float(v), 4) for v in MAD_TO_SIGMA * np.median(abs(r_err), 0)],
            'confidence_median': round(float(np.median([r[2] for r in rows])), 3),
            'n': len(rows)}
    return {'source': f'python -m bbpose_ros.cli.pose_spread on {len(frames)} frames of '
                      f'{dataset.name}, shipped weights, default settings, {date.today()}',
            'objects': objects}


def main(argv: list[str] | None = None) -> int:
    """Measure and write the file; returns 0."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--dataset', type=Path, default=Path(
        os.environ.get('BBPOSE_DATASET') or DEFAULT_DATASET))
    parser.add_argument('--out', type=Path, default=OUT)
    args = parser.parse_args(argv)
    content = measure(args.dataset)
    args.out.write_text(json.dumps(content, indent=2) + '\n')
    print(json.dumps(content, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
