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
How right the adaptation's pseudo labels are, scored against ground truth for the report.

``bbpose adapt`` never reads ground truth; this is the protocol's check, run on dev frames
whose labels exist: each judged pose is matched to the frame's ground-truth instance of its
object (LM-O has one per object), and a label is *right* when its mesh projects within
``RIGHT_PROJ_PX`` (mean 2D projection error) of the truth: a box and rotation good enough
to teach the detector and Q-Net. A pose on an object absent from the frame is wrong.
"""

from collections import defaultdict
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bbpose_ros.core.data.bop import BopFrame
from bbpose_ros.core.data.models import ObjectModel
from bbpose_ros.core.eval import metrics
from bbpose_ros.core.geometry.boxes import box_iou

RIGHT_PROJ_PX = 10.0


def label_errors(frame: BopFrame, model: ObjectModel, rotation: np.ndarray,
                 translation: np.ndarray, box_uv: np.ndarray) -> dict[str, float] | None:
    """
    Errors of one label against the frame's instance of its object, or None (absent).

    Returns {'proj_px', 're_deg', 'te_mm', 'box_iou'} (box IoU against ``bbox_obj``).
    """
    truths = [i for i in frame.instances if i.object_name == model.name]
    if not truths:
        return None
    truth = truths[0]
    args = (rotation, translation, truth.rotation, truth.translation)
    re_deg, te_m = metrics.cm_deg_errors(*args, model.symmetry_transforms)
    return {'proj_px': metrics.proj(*args, frame.camera.k, model.eval_points),
            're_deg': float(re_deg), 'te_mm': float(te_m) * 1000.0,
            'box_iou': float(box_iou(box_uv, truth.box_uv)[0, 0])}


def label_precision(verdicts: Mapping[str, Sequence[Any]], frames: Sequence[BopFrame],
                    models: Mapping[str, ObjectModel]) -> dict[str, Any]:
    """
    Precision of the verdicts of a recording, per verdict and per object.

    Args:
        verdicts: {frame key '<scene_id>/<image_id>': [selection.Verdict]}.
        frames: the BopFrames with ground truth, keyed the same way.
        models: {name: ObjectModel}.

    Returns:
        {'verdicts': {verdict: {'count', 'right'}}, 'accepted': {object: {'count', 'right',
        'box_iou_median', 'te_median_mm', 're_median_deg'}}}; 'right' is the share right.

    """
    by_key = {f'{f.scene_id}/{f.image_id}': f for f in frames}
    rows = defaultdict(list)
    for key, judged in verdicts.items():
        for verdict in judged:
            pose = verdict.pose
            errors = label_errors(by_key[key], models[pose.object_name], pose.rotation,
                                  pose.translation, pose.box_uv)
            rows[verdict.verdict, pose.object_name].append(errors)
    by_verdict = defaultdict(list)
    for (verdict, _), errors in rows.items():
        by_verdict[verdict] += errors
    accepted = {name: _summary(errors) for (verdict, name), errors in sorted(rows.items())
                if verdict == 'accepted'}
    return {'verdicts': {v: _summary(e, short=True) for v, e in sorted(by_verdict.items())},
            'accepted': accepted, 'accepted_all': _summary(by_verdict['accepted'])}


def _summary(errors, short=False):
    right = [e is not None and e['proj_px'] < RIGHT_PROJ_PX for e in errors]
    summary = {'count': len(errors), 'right': float(np.mean(right)) if errors else None}
    found = [e for e in errors if e is not None]
    if not short:
        for name, key in (('box_iou_median', 'box_iou'), ('te_median_mm', 'te_mm'),
                          ('re_median_deg', 're_deg')):
            summary[name] = float(np.median([e[key] for e in found])) if found else None
    return summary
