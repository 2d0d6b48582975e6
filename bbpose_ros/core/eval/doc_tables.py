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
What each generated table of the docs shows (``bbpose docs``, ``make docs``).

A table's name is its marker in the doc (``<!-- table: NAME -->``); its reports are the
files ``docs/reports/NAME.json``, made by the command in ``REPORT_COMMANDS``. To add a
figure to the docs, add a report (run its command) and a table here, then mark the table
where it goes and run ``make docs``.
"""

from bbpose_ros.core.eval.report_tables import (
    Column, ListTable, ObjectsTable, RunsTable, StagesTable)

_EVAL = 'bbpose eval --dataset ../shared/datasets/lmo'
_BENCH = 'bbpose bench --dataset ../shared/datasets/lmo --inference-threads 1'

# report name -> the command that wrote it (with --json docs/reports/NAME.json).
REPORT_COMMANDS = {
    'eval_detector': f'{_EVAL} --boxes detector',
    'eval_detector_fp32': f'{_EVAL} --boxes detector --inference-precision fp32',
    'eval_detector_norefine': f'{_EVAL} --boxes detector --no-refine',
    'eval_detector_dense': f'{_EVAL} --boxes detector --pose-source dense+qnet',
    'eval_detector_gtrot': f'{_EVAL} --boxes detector --rotation gt',
    'eval_detector_gtrot_norefine': f'{_EVAL} --boxes detector --rotation gt --no-refine',
    'eval_detector_boxmask': f'{_EVAL} --boxes detector --box-source dense_mask',
    'eval_detector_gtrot_boxmask': f'{_EVAL} --boxes detector --rotation gt '
                                   '--box-source dense_mask',
    'eval_detector_gtrot_norefine_boxmask': f'{_EVAL} --boxes detector --rotation gt '
                                            '--no-refine --box-source dense_mask',
    'eval_gt': f'{_EVAL} --boxes gt',
    'eval_gt_fp32': f'{_EVAL} --boxes gt --inference-precision fp32',
    'eval_gt_norefine': f'{_EVAL} --boxes gt --no-refine',
    'eval_gt_norefine_fp32': f'{_EVAL} --boxes gt --no-refine --inference-precision fp32',
    'eval_gt_dense': f'{_EVAL} --boxes gt --pose-source dense+qnet',
    'eval_gt_gt': f'{_EVAL} --boxes gt --rotation gt',
    'eval_gt_gt_norefine': f'{_EVAL} --boxes gt --rotation gt --no-refine',
    'eval_gt_gt_exact': f'{_EVAL} --boxes gt --rotation gt --perturb-gt 0,0',
    'eval_gt_gt_exact_dense': f'{_EVAL} --boxes gt --rotation gt --perturb-gt 0,0 '
                              '--pose-source dense+qnet',
    'eval_gt_gt_perturbed': f'{_EVAL} --boxes gt --rotation gt --perturb-gt 15,20',
    'eval_gt_gt_sweep': f'{_EVAL} --boxes gt --rotation gt ' + ' '.join(
        f'--perturb-gt {level}' for level in ('0,0', '5,10', '10,20', '15,20', '20,20',
                                              '30,20', '45,20')),
    'eval_gt_gt_ray_sweep': f'{_EVAL} --boxes gt --rotation gt --perturb-direction ray '
                            + ' '.join(f'--perturb-gt 0,{mm}' for mm in (0, 30, 60, 90, 120)),
    'bench': _BENCH,
    'bench_fp32': f'{_BENCH} --param inference_precision:=fp32',
    'bench_graph': f'{_BENCH} --graph --duration 120',
    'bench_graph_stream': f'{_BENCH} --graph --duration 120 --param tracking:=true '
                          '--param tracking_stream:=true',
    'bench_graph_stream_map': 'bbpose bench --dataset out/map_check/scenes --inference-threads 1 '
                              '--graph --duration 60 --param tracking:=true --param '
                              'tracking_stream:=true --param fixed_frame:=world (after make '
                              'map-check)',
    # Paced replays, per-frame against stream mode (the Makefile's stream-check target).
    **{f'stream_{bag}_{run}': 'make stream-check' for bag in ('path', 'dev')
       for run in ('perframe', 'stream', 'compare')},
    # The scene map on the dev frames as static scenes (the Makefile's map-check target).
    **dict.fromkeys(('map_none', 'map_causal', 'map_final', 'map_causal_5mm', 'map_final_5mm',
                     'map_compare_causal', 'map_compare_final', 'map_compare_causal_5mm',
                     'map_compare_final_5mm', 'map_orbit'), 'make map-check'),
    # bbpose adapt's two-fold block protocol (the Makefile's adapt-check target).
    'adapt_compare': 'make adapt-check',
    'adapt_labels_135': 'make adapt-check',
    'adapt_labels_24': 'make adapt-check',
}

_NETWORKS = Column('networks', ('config.detector_network', 'config.qnet_network'), '{}')
_RECALL = Column('recall@0.5 (visib >= 0.3)', ('detection.mean.recall_iou50_visib30',))
_AP50 = Column('AP50', ('detection.mean.ap50',))
_ROTATION = Column('rotation median (deg)', ('mean.re_median_deg',), '{:.1f}')
_TRANSLATION = Column('translation median (mm)', ('mean.te_median_mm',), '{:.0f}')
_ADD = Column('ADD(-S)', ('mean.add_s_recall',))
_CM5DEG5 = Column('5 cm / 5 deg', ('mean.cm5deg5',))
_PROJ = Column('2D projection 5 px', ('mean.proj5px',))

_MAP_RUNS = (
    ('each frame alone (`--fuse none`)', 'map_none'),
    ('the map up to each frame (`--fuse causal`)', 'map_causal'),
    ('the map after each scene (`--fuse final`)', 'map_final'),
    ('causal, camera error 5 mm / 0.5 deg', 'map_causal_5mm'),
    ('final, camera error 5 mm / 0.5 deg', 'map_final_5mm'),
)


def _paired_columns(arm: str) -> tuple[Column, ...]:
    """Return a comparison's difference and interval per figure (``arm``: B - A's name)."""
    figures = (('found', 'found'), ('ADD(-S)', 'add_s'), ('5 cm / 5 deg', 'cm5deg5'),
               ('proj 5 px', 'proj5px'))
    return tuple(column for title, key in figures for column in (
        Column(f'{title}: {arm}', (f'{{o}}.{key}.diff',), '{:+.3f}'),
        Column('95 % interval', (f'{{o}}.{key}.low', f'{{o}}.{key}.high'), '{:+.3f}')))


_RUNS = (
    ('detector boxes, Q-Net, refined (the defaults)', 'eval_detector'),
    ('detector boxes, not refined', 'eval_detector_norefine'),
    ('detector boxes, `--pose-source dense+qnet`', 'eval_detector_dense'),
    ('detector boxes, exact rotation, refined', 'eval_detector_gtrot'),
    ('detector boxes, exact rotation, not refined', 'eval_detector_gtrot_norefine'),
    ('detector boxes, `--box-source dense_mask`', 'eval_detector_boxmask'),
    ('detector boxes, `--box-source dense_mask`, exact rotation, refined',
     'eval_detector_gtrot_boxmask'),
    ('detector boxes, `--box-source dense_mask`, exact rotation, not refined',
     'eval_detector_gtrot_norefine_boxmask'),
    ('ground-truth boxes, Q-Net, refined', 'eval_gt'),
    ('ground-truth boxes, Q-Net, not refined', 'eval_gt_norefine'),
    ('ground-truth boxes, `--pose-source dense+qnet`', 'eval_gt_dense'),
    ('ground-truth boxes and rotations, refined', 'eval_gt_gt'),
    ('ground-truth boxes and rotations, not refined (the equation alone)',
     'eval_gt_gt_norefine'),
    ('the exact truth, refined (`--perturb-gt 0,0`)', 'eval_gt_gt_exact'),
    ('the exact truth, refined, `--pose-source dense+qnet`', 'eval_gt_gt_exact_dense'),
    ('the truth turned 15 deg and moved 20 mm, refined', 'eval_gt_gt_perturbed'),
)

# Per object: n, found, errors and recalls; with the detector its recall and AP50 first.
_PER_OBJECT = (
    Column('n', ('{o}.n',), '{:.0f}'),
    Column('found', ('{o}.detected',), '{:.1f}'),
    Column('rotation median (deg)', ('{o}.re_median_deg',), '{:.1f}'),
    Column('translation median (mm)', ('{o}.te_median_mm',), '{:.1f}'),
    Column('ADD(-S)', ('{o}.add_s_recall',)),
    Column('5 cm / 5 deg', ('{o}.cm5deg5',)),
    Column('2D projection 5 px', ('{o}.proj5px',)),
)
_DETECTION = (
    Column('recall, visib >= 0.3', ('{d}.recall_iou50_visib30',)),
    Column('recall, visib >= 0.1', ('{d}.recall_iou50',)),
    Column('AP50', ('{d}.ap50',)),
    Column('box size error (median)', ('{d}.size_error_median',), '{:+.3f}'),
    Column('box side error (RMS)', ('{d}.side_error_rms',)),
)

# Bench rows: label, keys (median / p95 / max), format.
_MS = ('median_ms', 'p95_ms', 'max_ms')


def _stage(label: str, stage: str) -> tuple[str, tuple[str, ...], str]:
    return (label, tuple(f'stages.{stage}.{s}' for s in _MS), '{:.2f}')


_STAGES = (
    _stage('image conversion (Image -> array)', 'image_conversion'),
    _stage('detector (640x480 -> 480x352)', 'detector'),
    _stage('crop + Q-Net, all objects (1 batch)', 'qnet'),
    _stage('ranking the 8 hypotheses', 'hypothesis_selection'),
    _stage('Bounding Box Equation, per object (3 hypotheses each)', 'bbox_equation_per_object'),
    _stage('refinement, the frame', 'refinement'),
    _stage('refinement, per object', 'refinement_per_object'),
    _stage('tracking refinement, the frame', 'tracking'),
    _stage('tracking refinement, per object', 'tracking_per_object'),
    _stage('message building', 'messages'),
    ('**whole frame**', tuple(f'total.{s}' for s in _MS), '{:.2f}'),
    ('frames per second', ('fps',), '{:.1f}'),
    ('objects per frame', ('objects_per_frame',), '{:.2f}'),
)

TABLES = {
    # README: one accuracy row, one speed row.
    'readme_accuracy': RunsTable(
        'README.md',
        (_NETWORKS, _RECALL, _ROTATION, _ADD, _CM5DEG5, _PROJ),
        (('the full pipeline (detector boxes, defaults)', 'eval_detector'),)),
    'readme_speed': RunsTable(
        'README.md',
        (Column('networks', ('detector_network', 'qnet_network'), '{}'),
         Column('detector', ('stages.detector.median_ms',), '{:.1f}'),
         Column('crop + Q-Net', ('stages.qnet.median_ms',), '{:.1f}'),
         Column('refinement per object', ('stages.refinement_per_object.median_ms',),
                '{:.1f}'),
         Column('whole frame, median / p95', ('total.median_ms', 'total.p95_ms'), '{:.1f}'),
         Column('whole frame, all objects, p95', ('all_objects.total.p95_ms',), '{:.1f}')),
        (('`bbpose bench`, defaults, median ms', 'bench'),)),
    # docs/results.md
    'results_runs': RunsTable(
        'docs/results.md',
        (_NETWORKS, _RECALL, _AP50, _ROTATION, _TRANSLATION, _ADD, _CM5DEG5, _PROJ), _RUNS),
    'results_precision': RunsTable(
        'docs/results.md',
        (_NETWORKS, _RECALL, _AP50, _ROTATION, _ADD, _CM5DEG5, _PROJ),
        (('detector boxes, refined, `auto`', 'eval_detector'),
         ('detector boxes, refined, `fp32`', 'eval_detector_fp32'),
         ('ground-truth boxes, refined, `auto`', 'eval_gt'),
         ('ground-truth boxes, refined, `fp32`', 'eval_gt_fp32'),
         ('ground-truth boxes, not refined, `auto`', 'eval_gt_norefine'),
         ('ground-truth boxes, not refined, `fp32`', 'eval_gt_norefine_fp32'))),
    'results_detector': ObjectsTable('docs/results.md', 'eval_detector',
                                     _DETECTION + _PER_OBJECT[1:]),
    'results_detector_norefine': ObjectsTable('docs/results.md', 'eval_detector_norefine',
                                              _DETECTION + _PER_OBJECT[1:]),
    'results_detector_dense': ObjectsTable(
        'docs/results.md', 'eval_detector_dense',
        _PER_OBJECT[1:] + (Column('Q-Net alone: ADD(-S) / 5 cm 5 deg / proj',
                                  ('{o}.add_s_recall', '{o}.cm5deg5', '{o}.proj5px'),
                                  report='eval_detector'),)),
    'results_gt': ObjectsTable('docs/results.md', 'eval_gt', _PER_OBJECT),
    'results_gt_norefine': ObjectsTable('docs/results.md', 'eval_gt_norefine', _PER_OBJECT),
    'results_bbox_equation': ObjectsTable('docs/results.md', 'eval_gt_gt_norefine',
                                          _PER_OBJECT),
    'readme_map': RunsTable(
        'README.md', (_ADD, _CM5DEG5, _PROJ, _TRANSLATION), _MAP_RUNS[:3]),
    # docs/results.md: the map of the scene
    'results_map': RunsTable(
        'docs/results.md',
        (_ROTATION, _TRANSLATION, _ADD, _CM5DEG5, _PROJ,
         Column('map, ms a frame: median / p95', ('timing_ms.map.median', 'timing_ms.map.p95'),
                '{:.1f}')), _MAP_RUNS),
    'results_map_causal': ObjectsTable(
        'docs/results.md', 'map_compare_causal', _paired_columns('causal - frame'),
        last=('figures', '**all instances**'), tool='bbpose compare'),
    'results_map_final': ObjectsTable(
        'docs/results.md', 'map_compare_final', _paired_columns('final - frame'),
        last=('figures', '**all instances**'), tool='bbpose compare'),
    'results_map_noise': RunsTable(
        'docs/results.md',
        tuple(column for title, key in (('ADD(-S)', 'add_s'), ('5 cm / 5 deg', 'cm5deg5'))
              for column in (Column(f'{title}: map - frame', (f'figures.{key}.diff',),
                                    '{:+.3f}'),
                             Column('95 % interval', (f'figures.{key}.low',
                                                      f'figures.{key}.high'), '{:+.3f}'))),
        (('causal, 2 mm / 0.2 deg', 'map_compare_causal'),
         ('causal, 5 mm / 0.5 deg', 'map_compare_causal_5mm'),
         ('final, 2 mm / 0.2 deg', 'map_compare_final'),
         ('final, 5 mm / 0.5 deg', 'map_compare_final_5mm')),
        first='camera error (TF)', tool='bbpose compare'),
    'results_map_orbit': ListTable(
        'docs/results.md', 'map_orbit', 'map.stability', Column('object', ('object',), '{}'),
        (Column('frames', ('frames',), '{:.0f}'),
         Column('spread of the position (RMS, mm)', ('translation_mm',), '{:.2f}'),
         Column('spread of the rotation (RMS, deg)', ('rotation_deg',), '{:.2f}'))),
    'results_map_moves': ListTable(
        'docs/results.md', 'map_orbit', 'map.moves', Column('object moved', ('object',), '{}'),
        (Column('at image', ('image_id',), '{:.0f}'),
         Column('frames until the map holds the new place', ('frames_to_follow',), '{:.0f}'))),
    # docs/training.md: bbpose adapt, adapted against shipped, paired over both folds
    'training_adapt_paired': ObjectsTable(
        'docs/training.md', 'adapt_compare',
        (Column('ADD(-S): shipped / adapted', ('{o}.add_s.a', '{o}.add_s.b')),)
        + _paired_columns('adapted - shipped'),
        last=('figures', '**all instances**'), tool='bbpose compare'),
    'training_adapt_labels': RunsTable(
        'docs/training.md',
        tuple(column for name in ('round1', 'round2') for column in (
            Column(f'{name}: labels', (f'{name}.accepted_all.count',), '{:.0f}'),
            Column('right', (f'{name}.accepted_all.right',), '{:.2f}'),
            Column('box IoU median', (f'{name}.accepted_all.box_iou_median',), '{:.2f}'),
            Column('translation median (mm)', (f'{name}.accepted_all.te_median_mm',),
                   '{:.0f}'))),
        (('adapted on blocks 1, 3, 5', 'adapt_labels_135'),
         ('adapted on blocks 2, 4', 'adapt_labels_24')), first='fold',
        tool='bbpose score-labels'),
    # docs/refinement.md
    'refinement_basin': ListTable(
        'docs/refinement.md', 'eval_gt_gt_sweep', 'sweep',
        Column('start: deg / mm off the truth', ('deg', 'mm'), '{:.0f}'),
        (Column('5 cm / 5 deg', ('mean.cm5deg5',)), Column('ADD(-S)', ('mean.add_s_recall',)),
         Column('rotation median (deg)', ('mean.re_median_deg',), '{:.1f}'))),
    'refinement_ray_basin': ListTable(
        'docs/refinement.md', 'eval_gt_gt_ray_sweep', 'sweep',
        Column('start: mm off the truth along the ray', ('mm',), '{:.0f}'),
        (Column('translation median (mm)', ('mean.te_median_mm',), '{:.1f}'),
         Column('ADD(-S)', ('mean.add_s_recall',)), Column('5 cm / 5 deg', ('mean.cm5deg5',)),
         Column('rotation median (deg)', ('mean.re_median_deg',), '{:.1f}'))),
    'refinement_confidence': ListTable(
        'docs/refinement.md', 'eval_detector', 'confidence',
        Column('minimum score', ('min_confidence',), '{:.1f}'),
        (Column('poses kept', ('kept',), '{:.2f}'),
         Column('kept passing ADD(-S)', ('add_s_precision',)),
         Column('kept within 5 cm / 5 deg', ('cm5deg5_precision',)))),
    # docs/performance.md
    'performance_stages': StagesTable(
        'docs/performance.md', _STAGES,
        (('detector mode', 'bench', ''), ('all objects', 'bench', 'all_objects.'),
         ('tracked frame', 'bench', 'tracking.'),
         ('all objects, fp32', 'bench_fp32', 'all_objects.'))),
    'performance_budgets': StagesTable(
        'docs/performance.md',
        tuple((name, (f'budgets.{name}.value', f'budgets.{name}.limit',
                      f'budgets.{name}.met'), '{:.2f}')
              for name in ('detector', 'qnet_all_objects', 'bbox_equation_per_object',
                           'refinement_per_object', 'tracking_per_object',
                           'frame_all_objects_p95', 'frame_tracking_p95')),
        (('`auto`: ms / limit / met', 'bench', ''), ('`fp32`', 'bench_fp32', '')),
        first='budget'),
    'performance_graph': RunsTable(
        'docs/performance.md',
        (Column('publish -> last pose: median / p95 / max',
                ('latency.median_ms', 'latency.p95_ms', 'latency.max_ms'), '{:.1f}'),
         Column('publish -> markers: p95', ('answer_latency.p95_ms',), '{:.1f}'),
         Column('answered / published', ('frames.answered', 'frames.published'), '{:.0f}'),
         Column('node CPU (% of a core)', ('node.cpu_percent',), '{:.0f}'),
         Column('node RSS start / end (MB)', ('node.rss_start_mb', 'node.rss_end_mb'),
                '{:.0f}'),
         Column('RSS growth (%)', ('node.rss_growth_percent',), '{:+.1f}')),
        (('30 Hz for 120 s, per frame', 'bench_graph'),
         ('30 Hz for 120 s, stream mode', 'bench_graph_stream'),
         ('30 Hz for 60 s, stream mode, `fixed_frame` (the map; dev scenes with camera TF)',
          'bench_graph_stream_map'))),
    'performance_stream': RunsTable(
        'docs/performance.md',
        (Column('answered / sent', ('frames.answered', 'frames.sent'), '{:.0f}'),
         Column('publish -> markers: median / p95 (ms)',
                ('timing_ms.answer.median', 'timing_ms.answer.p95'), '{:.1f}'),
         _ADD, _CM5DEG5, _PROJ),
        (('rendered 30 Hz camera path, per frame', 'stream_path_perframe'),
         ('rendered 30 Hz camera path, stream mode', 'stream_path_stream'),
         ('dev frames at 5 Hz, per frame', 'stream_dev_perframe'),
         ('dev frames at 5 Hz, stream mode', 'stream_dev_stream')),
        first='paced replay', tool='bbpose replay-eval --paced'),
    'performance_stream_paired': RunsTable(
        'docs/performance.md',
        tuple(column for title, key in (('found', 'found'), ('ADD(-S)', 'add_s'),
                                        ('5 cm / 5 deg', 'cm5deg5'), ('proj 5 px', 'proj5px'))
              for column in (Column(f'{title}: stream - per frame',
                                    (f'figures.{key}.diff',), '{:+.3f}'),
                             Column('95 % interval', (f'figures.{key}.low',
                                                      f'figures.{key}.high'), '{:+.3f}'))),
        (('rendered 30 Hz camera path', 'stream_path_compare'),
         ('dev frames at 5 Hz', 'stream_dev_compare')),
        first='paced replay', tool='bbpose compare'),
}
