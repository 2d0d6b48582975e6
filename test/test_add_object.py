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

"""A new object end to end: a red box's mesh -> weight files -> the node reports the box."""

import json

from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from test_ros_support import GraphClient, NodeLog, use_private_domain
import torch
import trimesh
import yaml

from bbpose_ros.bags import topics
from bbpose_ros.cli.add_object import base_weight_files, write_params
from bbpose_ros.cli.graph.replay import NodeProcess
from bbpose_ros.core.add_object.add_object_settings import (AddedObject, AddObjectSettings,
                                                            axis_symmetries)
from bbpose_ros.core.add_object.add_object_stages import (AddObject, INPLANE_RANGE_DEG,
                                                          NETWORKS, output_files)
from bbpose_ros.core.data.bop import load_camera
from bbpose_ros.core.data.mesh_check import check_mesh
from bbpose_ros.core.data.models import load_bop_models
from bbpose_ros.core.inference.weights import load_network, WEIGHTS_DIR
from bbpose_ros.core.synth.table_config import TableConfig
from bbpose_ros.core.synth.table_scenes import TableScenes
from bbpose_ros.core.training.object_rows import with_objects
from bbpose_ros.core.training.settings import RowTraining
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.conversions import rgb_to_image
from bbpose_ros.ros.params import check_value
from bbpose_ros.ros.params_file import pipeline_values

NAME = 'redbox'
# Small enough for CI, large enough for the detector to find the box in its own scenes.
TINY = AddObjectSettings(scenes=48, crops=160, scene_shard=48, crop_shard=160,
                         detector=RowTraining(steps=300, batch=8, passes=1),
                         qnet=RowTraining(steps=60, passes=1, seeds=2),
                         dense=RowTraining(steps=30, batch=8, passes=1), workers=2,
                         held_out=0.25)


@pytest.fixture(scope='module')
def red_box(tmp_path_factory):
    path = tmp_path_factory.mktemp('mesh') / 'box.ply'
    box = trimesh.creation.box((90.0, 60.0, 45.0))        # millimetres
    box.visual.vertex_colors = np.tile([210, 30, 30, 255], (len(box.vertices), 1))
    box.export(path)
    return check_mesh(path, 'mm')


@pytest.fixture(scope='module')
def added(lmo_root, red_box, tmp_path_factory):
    out = tmp_path_factory.mktemp('added')
    task = AddObject(AddedObject(NAME, red_box, np.zeros((0, 4, 4))),
                     base_weight_files(WEIGHTS_DIR), lmo_root, out, TINY, progress=False,
                     log=lambda line: None)
    task.run()
    write_params(out, task.pipeline_files())        # as bbpose add-object does
    return out


@pytest.mark.slow   # renders and trains
def test_the_networks_grow_by_one_object_and_keep_the_others(added):
    report = json.loads((added / 'report.json').read_text())
    assert report['objects'][-1] == NAME
    image = torch.rand(1, 3, 352, 480)
    base = load_network(WEIGHTS_DIR / 'detector.pt', 'detector').eval()
    grown = load_network(added / 'detector.pt', 'detector').eval()
    assert grown.config.objects == (*base.config.objects, NAME)
    with torch.no_grad():
        (heat_base, sides_base), (heat, sides) = base(image), grown(image)
    assert torch.equal(heat[:, :-1], heat_base) and torch.equal(sides, sides_base)
    for kind in ('qnet', 'dense'):
        network = load_network(added / f'{kind}.pt', kind)
        assert network.config.objects[-1] == NAME
    for graph in ('detector_int8.onnx', 'qnet_int8.onnx', 'preview.png'):
        assert (added / graph).stat().st_size > 0
    assert NAME in load_bop_models(added / 'dataset')
    # The renders are gone once nothing reads them; memory and disk are stated.
    assert not (added / 'renders').exists()
    assert report['peak_rss_mb'] > 100 and 0 < report['disk_mb'] < 100


@pytest.mark.slow   # renders and trains
def test_a_second_run_resumes_and_other_inputs_are_refused(lmo_root, red_box, added):
    before = (added / 'detector.pt').stat().st_mtime_ns
    lines = []
    AddObject(AddedObject(NAME, red_box, np.zeros((0, 4, 4))), base_weight_files(WEIGHTS_DIR),
              lmo_root, added, TINY, progress=False, log=lines.append).run()
    assert (added / 'detector.pt').stat().st_mtime_ns == before
    assert any(line.startswith('[detector] done before') for line in lines)
    assert not any(line.startswith('[renders]') for line in lines)     # not made again
    with pytest.raises(InputError, match='symmetries'):
        AddObject(AddedObject(NAME, red_box, axis_symmetries(red_box, 'z', 2)),
                  base_weight_files(WEIGHTS_DIR), lmo_root, added, TINY).run()


@pytest.mark.slow   # loads the three networks
def test_a_known_name_is_refused(lmo_root, red_box, tmp_path):
    with pytest.raises(InputError, match="'duck' already"):
        AddObject(AddedObject('duck', red_box, np.zeros((0, 4, 4))),
                  base_weight_files(WEIGHTS_DIR), lmo_root, tmp_path, TINY)


@pytest.mark.slow   # loads Q-Net
def test_with_objects_drops_rows_and_keeps_the_rest():
    qnet = load_network(WEIGHTS_DIR / 'qnet.pt', 'qnet').eval()
    without = with_objects(qnet, [n for n in qnet.config.objects if n != 'ape']).eval()
    crops = torch.rand(3, 3, 64, 64)
    index = torch.tensor([1, 4, 7])
    with torch.no_grad():
        assert torch.equal(qnet(crops, index), without(crops, index - 1))


def test_the_params_file_sets_node_parameters_as_the_node_declares_them(tmp_path):
    (tmp_path / 'dataset' / 'models').mkdir(parents=True)
    for kind in NETWORKS:
        (tmp_path / f'{kind}.pt').touch()
    files = output_files(tmp_path, ['ape', NAME])
    parameters = pipeline_values(files)
    out = tmp_path.resolve()
    assert parameters == {'objects': ['ape', NAME], 'dataset_dir': str(out / 'dataset'),
                          **{f'{kind}_weights': str(out / f'{kind}.pt') for kind in NETWORKS}}
    for name, value in parameters.items():
        check_value(name, value)      # ros/params.py's name, type and check
    written = yaml.safe_load(write_params(tmp_path, files).read_text())
    assert written == {'/**': {'ros__parameters': parameters}}


@pytest.mark.slow   # renders, trains and starts the node
def test_the_node_started_with_the_params_file_reports_the_new_object(added):
    """The node, with nothing but params.yaml, publishes the box's pose on a rendered frame."""
    models = load_bop_models(added / 'dataset')
    camera = load_camera(added / 'dataset')
    scenes = TableScenes({NAME: models[NAME]}, camera, TINY.seed,
                         TableConfig(inplane_range_deg=INPLANE_RANGE_DEG),
                         {n: m for n, m in models.items() if n != NAME})
    try:
        sample = scenes.sample(0)       # a training scene: the tiny detector knows it
    finally:
        scenes.close()
    assert [i.object_name for i in sample.instances] == [NAME]
    params = added / 'params_test.yaml'
    params.write_text((added / 'params.yaml').read_text() + '    score_threshold: 0.1\n')
    use_private_domain(offset=9)
    log = NodeLog(added / 'node.log')
    node = NodeProcess(params, stderr=log.file)
    client = GraphClient()
    try:
        image_pub = client.publisher(Image, topics.IMAGE_TOPIC)
        info_pub = client.publisher(CameraInfo, topics.CAMERA_INFO_TOPIC)
        client.subscribe(PoseStamped, f'/bbpose_node/{NAME}/pose')
        assert client.spin_until(lambda: image_pub.get_subscription_count() > 0
                                 and info_pub.get_subscription_count() > 0), log.path
        header = Header(frame_id='camera')
        header.stamp.sec = 1
        info = CameraInfo(header=header, width=camera.width, height=camera.height,
                          distortion_model='plumb_bob', d=[0.0] * 5,
                          k=camera.k.reshape(-1).tolist(),
                          r=np.eye(3).reshape(-1).tolist(),
                          p=np.hstack([camera.k, np.zeros((3, 1))]).reshape(-1).tolist())
        image_pub.publish(rgb_to_image(header, sample.image_rgb))
        info_pub.publish(info)
        assert client.spin_until(lambda: client.received[f'/bbpose_node/{NAME}/pose']), \
            log.path
        pose = client.received[f'/bbpose_node/{NAME}/pose'][0].pose.position
        truth = sample.instances[0].translation
        assert np.linalg.norm([pose.x - truth[0], pose.y - truth[1], pose.z - truth[2]]) < 0.3
    finally:
        client.close()
        node.stop()
