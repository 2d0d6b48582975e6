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
Compressed cameras: sensor_msgs/CompressedImage (JPEG, PNG) decoded, in bags and the node.

LM-O frames compressed as image_transport's compressed publisher does, decoded back by
``decode_compressed``; bad data refused naming the field.
"""

import json
import subprocess
import sys

import cv2
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import CameraInfo, CompressedImage
from test_ros_support import GraphClient, NodeLog, REPO_ROOT, TIMEOUT_S, use_private_domain
from test_ros_support import weight_files, write_params
from visualization_msgs.msg import MarkerArray

from bbpose_ros.bags import topics
from bbpose_ros.bags.reader import bag_image_source, read_bag_frames
from bbpose_ros.bags.typestore import TYPESTORE
from bbpose_ros.bags.writer import write_bag
from bbpose_ros.cli.graph.graph_bench import camera_messages
from bbpose_ros.cli.graph.replay import NodeProcess
from bbpose_ros.cli.main import main
from bbpose_ros.core.data.compressed_image import codec_of, compressed_size
from bbpose_ros.core.data.compressed_image import decode_compressed, encode_compressed
from bbpose_ros.core.data.stamps import stamp_to_ns
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros import conversions
from bbpose_ros.ros.diagnostics import counts_from_status

# Mean absolute difference per channel (grey levels, 0..255) of a quality-95 JPEG of an LM-O
# frame against the frame: a few tenths measured; swapped channels are off by over 10.
JPEG_TOLERANCE = 2.0
BAG_FRAMES = 3
MARKERS = '/bbpose_node/markers'
START_S = 1_700_000_000


@pytest.fixture(scope='module')
def frame(lmo_frames):
    return lmo_frames[0].load_image()


def error(decoded, original):
    return np.abs(decoded.astype(float) - original).mean()


def test_png_comes_back_bit_exact(frame):
    image_format, data = encode_compressed(frame, 'png')
    assert image_format == 'rgb8; png compressed bgr8'
    assert np.array_equal(decode_compressed(image_format, data), frame)


def test_jpeg_comes_back_close_in_its_colours(frame):
    image_format, data = encode_compressed(frame, 'jpeg')
    assert image_format == 'rgb8; jpeg compressed bgr8'
    decoded = decode_compressed(image_format, data)
    assert decoded.shape == frame.shape and decoded.dtype == np.uint8
    assert error(decoded, frame) < JPEG_TOLERANCE
    assert error(decoded[:, :, ::-1], frame) > 5 * JPEG_TOLERANCE
    smaller = encode_compressed(frame, 'jpeg', jpeg_quality=50)[1]
    assert len(smaller) < len(data)


def test_mono_comes_back_grey_in_three_channels(frame):
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    for codec in ('jpeg', 'png'):
        image_format, data = encode_compressed(grey, codec)
        assert image_format == f'mono8; {codec} compressed mono8'
        decoded = decode_compressed(image_format, data)
        assert decoded.shape == frame.shape
        assert np.array_equal(decoded[:, :, 0], decoded[:, :, 2])
        assert error(decoded[:, :, 0], grey) < (JPEG_TOLERANCE if codec == 'jpeg' else 1e-9)


def test_channel_order_follows_the_format(frame):
    # A publisher that compressed RGB pixels says so; a bare 'png' is OpenCV's BGR.
    ok, data = cv2.imencode('.png', frame)          # RGB pixels written as they are
    assert ok
    assert np.array_equal(decode_compressed('rgb8; png compressed rgb8', data), frame)
    assert np.array_equal(decode_compressed('png', data)[:, :, ::-1], frame)
    ok, data = cv2.imencode('.png', cv2.cvtColor(frame, cv2.COLOR_RGB2BGRA))
    assert np.array_equal(decode_compressed('bgra8; png compressed bgra8', data), frame)


@pytest.mark.parametrize('codec', ['jpeg', 'png'])
def test_truncated_data_is_refused_naming_it(frame, codec):
    image_format, data = encode_compressed(frame, codec)
    for size in (len(data) - 1, len(data) // 2, 30, 3):
        with pytest.raises(InputError, match=r'truncated.*\(field data\)|\(field data\).*'
                                             'truncated'):
            decode_compressed(image_format, data[:size])


def test_bad_data_and_formats_are_refused_naming_the_field(frame):
    jpeg_format, jpeg = encode_compressed(frame, 'jpeg')
    png_format, png = encode_compressed(frame, 'png')
    middle = len(png) // 2
    cases = [
        (jpeg_format, b'', r'empty compressed image \(field data\)'),
        (jpeg_format, png, r'data is not a jpeg image \(field data\)'),
        (png_format, jpeg, r'data is not a png image \(field data\)'),
        (png_format, png[:middle] + bytes(1000) + png[middle + 1000:],
         r'cannot be decoded \(field data\): corrupt'),
        ('16UC1; compressedDepth png', png, r'compressedDepth\) \(field format\)'),
        ('rgb8; tiff compressed bgr8', png, r'unsupported compressed image format '
                                            r'"rgb8; tiff compressed bgr8" \(field format\)'),
    ]
    for image_format, data, pattern in cases:
        with pytest.raises(InputError, match=pattern):
            decode_compressed(image_format, data)
    ok, sixteen = cv2.imencode('.png', frame.astype(np.uint16) * 256)
    assert ok
    with pytest.raises(InputError, match=r'16-bit pixels \(field data\)'):
        decode_compressed('rgb16; png compressed bgr16', sixteen)


def test_an_image_over_the_pixel_limit_is_refused_before_decoding(frame):
    image_format, data = encode_compressed(frame, 'jpeg')
    assert compressed_size('jpeg', data) == (640, 480)
    assert compressed_size('png', encode_compressed(frame, 'png')[1]) == (640, 480)
    with pytest.raises(InputError, match=r'640x480 pixels, more than the limit of 1000'):
        decode_compressed(image_format, data, max_pixels=1000)
    assert decode_compressed(image_format, data, max_pixels=640 * 480).shape == frame.shape


def test_codec_names_as_publishers_write_them():
    assert codec_of('rgb8; jpeg compressed bgr8') == 'jpeg'
    assert codec_of('bgr8; png compressed bgr8') == 'png'
    assert codec_of('jpeg') == 'jpeg' and codec_of('JPG') == 'jpeg' and codec_of('png') == 'png'


# --- bags: make-bag --compressed, read back by read_bag_frames ---------------------------

def make_bag(lmo_root, out, *args):
    """Run ``bbpose make-bag`` on the first frames of LM-O; returns the exit code."""
    return main(['make-bag', '--dataset', str(lmo_root), '--out', str(out), '--max-frames',
                 str(BAG_FRAMES), '--start-stamp', '1700000000', *args])


def bag_bytes(path):
    return sum(f.stat().st_size for f in path.iterdir())


def test_a_compressed_bag_reads_back_close_to_the_raw_one(lmo_root, tmp_path, capsys):
    assert make_bag(lmo_root, tmp_path / 'raw') == 0
    assert make_bag(lmo_root, tmp_path / 'jpeg', '--compressed') == 0
    assert make_bag(lmo_root, tmp_path / 'q50', '--compressed', '--jpeg-quality', '50') == 0
    out = capsys.readouterr().out
    assert f'wrote {BAG_FRAMES} frames (JPEG, quality 95)' in out
    assert f'wrote {BAG_FRAMES} frames (JPEG, quality 50)' in out
    assert bag_bytes(tmp_path / 'q50') < bag_bytes(tmp_path / 'jpeg') < bag_bytes(tmp_path / 'raw')
    with Reader(tmp_path / 'jpeg') as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
    assert types[topics.compressed_topic(topics.IMAGE_TOPIC)] == topics.COMPRESSED_IMAGE_TYPE
    assert topics.IMAGE_TOPIC not in types
    assert bag_image_source(tmp_path / 'jpeg') == ('/camera/image_raw/compressed', 'compressed')
    assert bag_image_source(tmp_path / 'raw') == ('/camera/image_raw', 'raw')

    raw, jpeg = read_bag_frames(tmp_path / 'raw'), read_bag_frames(tmp_path / 'jpeg')
    assert len(jpeg) == len(raw) == BAG_FRAMES
    for original, copy in zip(raw, jpeg):
        assert copy.stamp_ns == original.stamp_ns and copy.frame_id == original.frame_id
        assert copy.image_rgb.shape == original.image_rgb.shape
        assert error(copy.image_rgb, original.image_rgb) < JPEG_TOLERANCE
        np.testing.assert_allclose(copy.camera.k, original.camera.k)
        assert copy.ground_truth.keys() == original.ground_truth.keys()
    # The compressed topic named directly reads the same frames.
    named = read_bag_frames(tmp_path / 'jpeg', topics.compressed_topic(topics.IMAGE_TOPIC))
    assert all(np.array_equal(a.image_rgb, b.image_rgb) for a, b in zip(named, jpeg))


def test_make_bag_takes_a_jpeg_quality_only_for_compressed_bags(lmo_root, tmp_path, capsys):
    assert make_bag(lmo_root, tmp_path / 'bag', '--jpeg-quality', '80') == 2
    assert '--jpeg-quality is for --compressed bags' in capsys.readouterr().err
    assert make_bag(lmo_root, tmp_path / 'bag', '--compressed', '--jpeg-quality', '0') == 2
    assert 'jpeg quality must be within 1 .. 100' in capsys.readouterr().err
    assert not (tmp_path / 'bag').exists()


def test_a_bad_frame_in_a_compressed_bag_is_named(lmo_frames, tmp_path):
    image_format, data = encode_compressed(lmo_frames[0].load_image())
    message = TYPESTORE.types[topics.COMPRESSED_IMAGE_TYPE](
        header=topics.header(5, 'cam'), format=image_format,
        data=np.frombuffer(data[:len(data) // 2], np.uint8))
    topic = topics.compressed_topic(topics.IMAGE_TOPIC)
    write_bag(tmp_path / 'bag', [(topic, topics.COMPRESSED_IMAGE_TYPE, 5, TYPESTORE.serialize_cdr(
        message, topics.COMPRESSED_IMAGE_TYPE).tobytes())])
    with pytest.raises(InputError, match=f'{topic} at stamp 5 ns: jpeg data .* truncated'):
        read_bag_frames(tmp_path / 'bag')


# --- the node: image_transport compressed ------------------------------------------------

@pytest.fixture(scope='module')
def compressed_node(lmo, lmo_root, tmp_path_factory):
    """Start a node with image_transport compressed and a client that publishes to it."""
    use_private_domain(offset=13)
    folder = tmp_path_factory.mktemp('compressed_node')
    log = NodeLog(folder / 'node.log')
    node = NodeProcess(write_params(folder / 'params.yaml', lmo_root, weight_files(folder),
                                    image_transport='compressed'), stderr=log.file)
    client = GraphClient()
    client.image = client.publisher(CompressedImage, topics.compressed_topic(topics.IMAGE_TOPIC))
    client.info = client.publisher(CameraInfo, topics.CAMERA_INFO_TOPIC)
    client.subscribe(MarkerArray, MARKERS)
    client.subscribe(DiagnosticArray, '/diagnostics')
    image, client.info_message = camera_messages(lmo.frames()[:1])[0]
    client.rgb = conversions.image_to_rgb(image)
    assert client.connected((client.image, client.info), MARKERS), log.path
    yield client, node, log
    client.close()
    node.stop()


def send(client, stamp_s, data_of=lambda data: data, codec='jpeg'):
    """Publish the frame compressed (``data_of`` may spoil it) with its CameraInfo."""
    image_format, data = encode_compressed(client.rgb, codec)
    message = CompressedImage(format=image_format, data=data_of(data))
    message.header.frame_id = client.info_message.header.frame_id
    message.header.stamp.sec = client.info_message.header.stamp.sec = stamp_s
    message.header.stamp.nanosec = client.info_message.header.stamp.nanosec = 0
    client.image.publish(message)
    client.info.publish(client.info_message)
    return stamp_s * 10 ** 9


def answered(client, stamp_ns, timeout_s=TIMEOUT_S):
    """Whether the MarkerArray of ``stamp_ns`` arrives within the timeout."""
    return client.spin_until(lambda: any(
        stamp_to_ns(m.markers[0].header.stamp) == stamp_ns
        for m in client.received[MARKERS]), timeout_s)


def node_counts(client):
    """Return the counters of the next /diagnostics status."""
    client.received['/diagnostics'].clear()
    client.spin_until(lambda: client.received['/diagnostics'])
    return counts_from_status(client.received['/diagnostics'][-1].status[0])


@pytest.mark.slow
def test_the_node_answers_compressed_frames(compressed_node):
    client, node, log = compressed_node
    assert answered(client, send(client, START_S)), log.path
    assert answered(client, send(client, START_S + 1, codec='png')), log.path
    assert log.wait_for('serving', '/camera/image_raw/compressed'), log.path
    client.received['/diagnostics'].clear()
    assert client.spin_until(lambda: client.received['/diagnostics'])
    keys = {value.key for value in client.received['/diagnostics'][-1].status[0].values}
    assert 'image_decode_ms_median' in keys         # the worker's decode, timed
    node.check_alive()


@pytest.mark.slow
def test_the_node_drops_a_truncated_frame_and_keeps_serving(compressed_node):
    client, node, log = compressed_node
    before = node_counts(client)
    log.mark()
    truncated = send(client, START_S + 10, data_of=lambda data: data[:len(data) // 2])
    assert log.wait_for('ERROR', 'compressed image on /camera/image_raw/compressed dropped',
                        'truncated', '(field data)'), log.path
    assert client.spin_until(lambda: node_counts(client)['bad_image'] > before['bad_image'])
    assert answered(client, send(client, START_S + 11)), log.path
    assert not answered(client, truncated, timeout_s=0.5)
    node.check_alive()


@pytest.mark.slow
def test_replay_eval_plays_a_compressed_bag_to_a_compressed_node(lmo_root, tmp_path, capsys):
    use_private_domain(offset=14)
    assert make_bag(lmo_root, tmp_path / 'bag', '--compressed') == 0
    params = write_params(tmp_path / 'params.yaml', lmo_root, weight_files(tmp_path))
    out = tmp_path / 'report.json'
    arguments = ['replay-eval', '--bag', tmp_path / 'bag', '--json', out, '--params', params]
    # Refused before any node starts: in this process (a real process's exit code 2 is
    # checked by test_cli.py).
    capsys.readouterr()
    assert main([str(a) for a in arguments] + ['--param', 'image_transport:=raw']) == 2
    assert 'the bag holds compressed images' in capsys.readouterr().err
    result = subprocess.run([sys.executable, '-m', 'bbpose_ros.cli.main', *arguments],
                            capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    assert result.returncode == 0, result.stderr
    assert f'{BAG_FRAMES} sent, {BAG_FRAMES} answered' in result.stdout
    report = json.loads(out.read_text())
    assert report['config']['image_transport'] == 'compressed'
    assert report['frames'] == {'sent': BAG_FRAMES, 'answered': BAG_FRAMES}
