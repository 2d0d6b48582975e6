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

"""The mesh check of a new object, and ``bbpose check-mesh``, on written PLY meshes."""

import json
import shutil

import numpy as np
import pytest
import trimesh

from bbpose_ros.cli.main import main
from bbpose_ros.core.data import mesh_check
from bbpose_ros.core.data.mesh_check import check_mesh, cluster_vertices, edge_counts, \
    write_bop_model
from bbpose_ros.core.data.models import load_bop_models, load_mesh
from bbpose_ros.core.util.errors import InputError

BOX_MM = (60.0, 40.0, 20.0)
RED = (200, 30, 30)


def write_ply(path, mesh, colors=None):
    """Write ``mesh`` as a PLY at ``path`` (vertex colours when given); return the path."""
    if colors is not None:
        mesh.visual.vertex_colors = np.tile([*colors, 255], (len(mesh.vertices), 1))
    path.write_bytes(mesh.export(file_type='ply'))
    return path


def box(scale=1.0):
    """Return a closed box of BOX_MM millimetres, times ``scale``."""
    return trimesh.creation.box(extents=np.array(BOX_MM) * scale)


def test_a_coloured_box_in_mm_passes_with_its_models_info_entry(tmp_path):
    checked = check_mesh(write_ply(tmp_path / 'part.ply', box(), RED))
    assert checked.notes == () and checked.open_edges == 0
    assert checked.diameter_m == pytest.approx(np.linalg.norm(BOX_MM) / 1000)
    assert np.all(checked.colors == RED)
    entry = checked.models_info_entry()
    assert entry['diameter'] == pytest.approx(np.linalg.norm(BOX_MM), abs=1e-3)
    assert [entry[f'size_{axis}'] for axis in 'xyz'] == pytest.approx(BOX_MM)
    assert [entry[f'min_{axis}'] for axis in 'xyz'] == pytest.approx(np.array(BOX_MM) / -2)


def test_a_box_without_colours_needs_a_uniform_one(tmp_path):
    path = write_ply(tmp_path / 'grey.ply', box())
    with pytest.raises(InputError, match=r'grey\.ply: no vertex colours .*--color R,G,B'):
        check_mesh(path)
    assert np.all(check_mesh(path, color=(1, 2, 3)).colors == (1, 2, 3))


def test_metres_declared_as_mm_are_named_with_the_numbers(tmp_path):
    path = write_ply(tmp_path / 'part_m.ply', box(1e-3), RED)
    with pytest.raises(InputError, match=r'part_m\.ply: units: diameter 0\.07483 .*as mm.*'
                                         r'as m it is 0\.07483 m: the file looks like m'):
        check_mesh(path, 'mm')
    assert check_mesh(path, 'm').diameter_m == pytest.approx(0.0748, abs=1e-4)
    with pytest.raises(InputError, match='looks like mm, not m'):
        check_mesh(write_ply(tmp_path / 'part_mm.ply', box(), RED), 'm')


def test_the_duck_scaled_to_metres_is_the_wrong_units(lmo_root, tmp_path):
    duck = trimesh.load(lmo_root / 'models' / 'obj_000009.ply', process=False)
    duck.apply_scale(1e-3)
    path = tmp_path / 'duck_m.ply'
    path.write_bytes(duck.export(file_type='ply'))
    with pytest.raises(InputError, match=r'units: diameter 0\.109 \(file units\) is 0\.000109 '
                                         r'm as mm.*the file looks like m, not mm'):
        check_mesh(path, 'mm')
    checked = check_mesh(path, 'm')
    assert checked.diameter_m == pytest.approx(0.108999, abs=1e-5)
    assert len(np.unique(checked.colors, axis=0)) > 10      # its own vertex colours


def test_a_size_plausible_in_no_unit_is_refused(tmp_path):
    path = write_ply(tmp_path / 'huge.ply', box(1e5), RED)
    with pytest.raises(InputError, match=r'huge\.ply: size: diameter .* outside 0.01-1 m'):
        check_mesh(path, 'mm')


def test_an_open_mesh_is_flagged_with_its_open_edges(tmp_path):
    mesh = box()
    open_box = trimesh.Trimesh(mesh.vertices, mesh.faces[1:], process=False)
    checked = check_mesh(write_ply(tmp_path / 'open.ply', open_box, RED))
    assert checked.open_edges == 3
    assert any('not watertight: 3 open edges' in note for note in checked.notes)
    assert edge_counts(mesh.faces) == (0, 0)


def test_a_huge_mesh_is_decimated_and_written_as_a_bop_model(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=50.0)     # 20480 faces
    checked = check_mesh(write_ply(tmp_path / 'ball.ply', sphere, RED), max_faces=2000)
    assert 500 < len(checked.faces) <= 2000
    assert 'decimated to' in checked.notes[0]
    assert checked.diameter_m == pytest.approx(0.1, rel=0.02)
    write_bop_model(checked, tmp_path / 'ds' / 'models', 16, 'ball')
    vertices, faces, colors = load_mesh(tmp_path / 'ds' / 'models' / 'obj_000016.ply')
    np.testing.assert_allclose(vertices, checked.vertices, atol=1e-6)
    assert np.all(colors == RED)
    models = load_bop_models(tmp_path / 'ds')
    assert list(models) == ['ball'] and models['ball'].obj_id == 16
    assert models['ball'].diameter == pytest.approx(checked.diameter_m, abs=1e-6)


def test_vertex_clustering_merges_and_keeps_colours():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    colors = np.tile(np.array(RED, dtype=np.uint8), (len(sphere.vertices), 1))
    vertices, faces, merged = cluster_vertices(sphere.vertices, sphere.faces, colors, 0.3)
    assert len(faces) < len(sphere.faces) and faces.max() == len(vertices) - 1
    assert np.all(merged == RED)
    assert np.all(np.abs(np.linalg.norm(vertices, axis=1) - 1.0) < 0.2)


def test_writing_refuses_bad_names_and_leaves_nothing_half_written(tmp_path, monkeypatch):
    checked = check_mesh(write_ply(tmp_path / 'part.ply', box(), RED))
    with pytest.raises(InputError, match='invalid object name'):
        write_bop_model(checked, tmp_path / 'bad', 1, 'my part')
    (tmp_path / 'taken').mkdir()
    with pytest.raises(InputError, match='already exists'):
        write_bop_model(checked, tmp_path / 'taken', 1, 'part')

    def full_disk(path, data):
        raise OSError('disk full')

    monkeypatch.setattr(mesh_check, 'write_json_atomic', full_disk)
    with pytest.raises(OSError, match='disk full'):
        write_bop_model(checked, tmp_path / 'out', 1, 'part')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['part.ply', 'taken']


def test_the_command_reports_refuses_and_writes(tmp_path, capsys):
    grey = write_ply(tmp_path / 'grey.ply', box())
    assert main(['check-mesh', '--mesh', str(grey), '--out', str(tmp_path / 'm')]) == 2
    assert 'grey.ply: no vertex colours' in capsys.readouterr().err
    assert not (tmp_path / 'm').exists()
    assert main(['check-mesh', '--mesh', str(grey), '--color', '10,200,30', '--name', 'toy',
                 '--obj-id', '3', '--out', str(tmp_path / 'm')]) == 0
    assert 'diameter 0.0748 m' in capsys.readouterr().out
    assert json.loads((tmp_path / 'm' / 'models_names.json').read_text()) == {'3': 'toy'}
    assert set(json.loads((tmp_path / 'm' / 'models_info.json').read_text())) == {'3'}
    shutil.rmtree(tmp_path / 'm')
    assert main(['check-mesh', '--mesh', str(grey), '--color', '10,200,30', '--name',
                 'toy']) == 2
    assert '--out' in capsys.readouterr().err
