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

"""config/bbpose.yaml is what the parameters' declarations make (``make config``)."""

import yaml

from bbpose_ros.cli.config_file import CONFIG_FILE, config_text, main
from bbpose_ros.ros.params import PARAMETERS
from bbpose_ros.ros.params_file import yaml_value


def test_the_parameters_file_is_what_the_declarations_make():
    assert CONFIG_FILE.read_text() == config_text(), \
        'config/bbpose.yaml differs from the declarations: run `make config`'


def test_every_parameter_reads_back_as_its_default_and_type():
    values = yaml.safe_load(config_text())['/**']['ros__parameters']
    assert list(values) == list(PARAMETERS)
    for name, spec in PARAMETERS.items():
        assert values[name] == spec.default and type(values[name]) is type(spec.default), name


def test_values_the_yaml_would_misread_are_quoted():
    for value in ('', '~/', 'null', 'true', '1.5', "it's", 'a: b', 'dense+qnet'):
        assert yaml.safe_load(yaml_value(value)) == value
    assert yaml_value(1.0) == '1.0' and yaml_value(1) == '1' and yaml_value(False) == 'false'
    for value in (1e-05, -2.5e-10, float('inf'), [0.5, 1e20]):
        assert yaml.safe_load(yaml_value(value)) == value


def test_check_tells_a_file_that_differs(tmp_path):
    path = tmp_path / 'bbpose.yaml'
    assert main([str(path), '--check']) == 1
    assert main([str(path)]) == 0 and path.read_text() == config_text()
    assert main([str(path), '--check']) == 0
    path.write_text(config_text().replace('score_threshold: 0.3', 'score_threshold: 0.4'))
    assert main([str(path), '--check']) == 1
