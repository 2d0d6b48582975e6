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
The package's import rules, read from the source (AST): layers point one way.

cli -> bags, ros -> core; the core imports no ROS and nothing of ros/, bags/ or cli/; bags/
reads and writes bags without ROS, but for its player (which publishes into the graph, and
which no other module of bags/ reaches); ros/ imports nothing of cli/ or bags/; in the core,
training may use synth but never the other way, adaptation (self-training) sits above
training and eval, as add-object (core/add_object) sits above training, neither imports the
other, and the running node reaches nothing of core/eval, core/training, core/synth,
core/adaptation, core/add_object or cli through any chain of imports; ``bbpose train``
needs no ROS, and no ``bbpose`` command imports another (what two share lives in
cli/common.py or the core); core/util (a leaf) imports nothing else of the package. No
module imports itself through a chain of others (no circle, lazy and type-checking imports
included), and no two modules share a file name.
"""

import ast
from pathlib import Path

import pytest

from bbpose_ros.cli.main import SUBCOMMANDS

PACKAGE = Path(__file__).parents[1] / 'bbpose_ros'
PLAYER = 'bbpose_ros.bags.player'
ROS_ROOTS = ('rclpy', 'rosidl_runtime_py', 'rcl_interfaces', 'builtin_interfaces',
             'ament_index_python', 'launch', 'launch_ros', 'tf2_ros', 'cv_bridge',
             'message_filters')


def _module_name(path):
    parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


PATHS = sorted(PACKAGE.rglob('*.py'))
KNOWN = {_module_name(p) for p in PATHS}


def _imports(path):
    """
    Return every module name the file imports, at any depth (lazy imports count).

    ``from a import b`` names a.b when that is a module of the package (a package's
    submodule), else a.
    """
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            submodules = {f'{node.module}.{alias.name}' for alias in node.names} & KNOWN
            names.update(submodules)
            if len(submodules) < len(node.names):
                names.add(node.module)
    return names


MODULES = {_module_name(p): _imports(p) for p in PATHS}


def _internal(names):
    """Keep the package's own modules among ``names`` (``from a import b`` may name one)."""
    return {n for n in names if n in MODULES}


def _is_ros(name):
    root = name.split('.')[0]
    return root in ROS_ROOTS or root.endswith(('_msgs', '_srvs', '_interfaces'))


def _violations(prefix, forbidden):
    return sorted(f'{module} imports {name}'
                  for module, names in MODULES.items() if _in(module, prefix)
                  for name in names if any(_in(name, f) for f in forbidden))


def _in(name, prefix):
    return name == prefix or name.startswith(prefix + '.')


def test_the_scan_sees_the_package():
    assert 'bbpose_ros.ros.node' in MODULES
    assert 'bbpose_ros.core.pipeline.loader' in _internal(MODULES['bbpose_ros.ros.node_pipeline'])
    assert len(MODULES) >= 60


@pytest.mark.parametrize('layer, forbidden', [
    ('bbpose_ros.core', ('bbpose_ros.ros', 'bbpose_ros.bags', 'bbpose_ros.cli')),
    ('bbpose_ros.ros', ('bbpose_ros.bags', 'bbpose_ros.cli')),
    ('bbpose_ros.bags', ('bbpose_ros.ros', 'bbpose_ros.cli')),
    ('bbpose_ros.core.synth', ('bbpose_ros.core.training', 'bbpose_ros.core.eval')),
    ('bbpose_ros.core.render', ('bbpose_ros.core.synth', 'bbpose_ros.core.training')),
    ('bbpose_ros.core.nets', ('bbpose_ros.core.pipeline', 'bbpose_ros.core.eval',
                              'bbpose_ros.core.training')),
    ('bbpose_ros.core.pipeline', ('bbpose_ros.core.eval', 'bbpose_ros.core.training',
                                  'bbpose_ros.core.synth')),
    ('bbpose_ros.core.geometry', ('bbpose_ros.core.data', 'bbpose_ros.core.nets',
                                  'bbpose_ros.core.pipeline', 'bbpose_ros.core.eval',
                                  'bbpose_ros.core.render', 'bbpose_ros.core.synth',
                                  'bbpose_ros.core.training')),
    ('bbpose_ros.core.data', ('bbpose_ros.core.nets', 'bbpose_ros.core.pipeline',
                              'bbpose_ros.core.eval', 'bbpose_ros.core.render',
                              'bbpose_ros.core.synth', 'bbpose_ros.core.training')),
    ('bbpose_ros.core.eval', ('bbpose_ros.core.training', 'bbpose_ros.core.synth',
                              'bbpose_ros.core.adaptation', 'bbpose_ros.core.add_object')),
    ('bbpose_ros.core.training', ('bbpose_ros.core.adaptation', 'bbpose_ros.core.add_object')),
    ('bbpose_ros.core.adaptation', ('bbpose_ros.core.add_object',)),
    ('bbpose_ros.core.add_object', ('bbpose_ros.core.adaptation',)),
    ('bbpose_ros.core.refine', ('bbpose_ros.core.nets', 'bbpose_ros.core.pipeline',
                                'bbpose_ros.core.eval', 'bbpose_ros.core.render',
                                'bbpose_ros.core.synth', 'bbpose_ros.core.training')),
    ('bbpose_ros.cli.train', ('bbpose_ros.ros', 'bbpose_ros.bags', 'bbpose_ros.cli.graph')),
])
def test_layers_import_one_way(layer, forbidden):
    assert _violations(layer, forbidden) == []


def test_util_is_a_leaf():
    assert sorted(f'{module} imports {name}' for module, names in MODULES.items()
                  if _in(module, 'bbpose_ros.core.util')
                  for name in _internal(names) if not _in(name, 'bbpose_ros.core.util')) == []


def test_no_command_imports_another():
    commands = [f'bbpose_ros.cli.{name}' for name in SUBCOMMANDS]
    offenders = sorted(f'{module} imports {name}' for module, names in MODULES.items()
                       for command in commands if _in(module, command)
                       for name in names for other in commands
                       if other != command and _in(name, other))
    assert offenders == []


def _circles():
    """Return the import circles: strongly connected groups of modules (Tarjan)."""
    index, low, stack, on_stack, circles = {}, {}, [], set(), []

    def visit(module):
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for name in _internal(MODULES[module]) - {module}:
            if name not in index:
                visit(name)
                low[module] = min(low[module], low[name])
            elif name in on_stack:
                low[module] = min(low[module], index[name])
        if low[module] == index[module]:
            group = {stack.pop()}
            while module not in group:
                group.add(stack.pop())
            on_stack.difference_update(group)
            if len(group) > 1:
                circles.append(sorted(group))

    for module in MODULES:
        if module not in index:
            visit(module)
    return circles


def test_no_import_circles():
    assert _circles() == []


def test_no_two_modules_share_a_name():
    names = [p.name for p in PACKAGE.rglob('*.py') if p.name != '__init__.py']
    assert sorted({n for n in names if names.count(n) > 1}) == []


def test_core_and_bags_import_no_ros():
    offenders = sorted(f'{module} imports {name}' for module, names in MODULES.items()
                       if _in(module, 'bbpose_ros.core') or _in(module, 'bbpose_ros.bags')
                       if module != PLAYER
                       for name in names if _is_ros(name))
    assert offenders == []


def _reached(start):
    """Return the package's modules that importing ``start`` runs, ``start`` included."""
    reached, todo = set(), [start]
    while todo:
        module = todo.pop()
        if module not in reached:
            reached.add(module)
            todo.extend(_internal(MODULES[module]))
            parent = module.rpartition('.')[0]
            if parent in MODULES:       # importing a module runs its package's __init__ too
                todo.append(parent)
    return reached


def test_bag_files_are_read_and_written_without_the_player():
    assert PLAYER in MODULES
    assert sorted(module for module in MODULES if _in(module, 'bbpose_ros.bags')
                  if module != PLAYER and PLAYER in _reached(module)) == []


def test_the_node_reaches_no_offline_code():
    reached = _reached('bbpose_ros.ros.node')
    offline = ('bbpose_ros.core.eval', 'bbpose_ros.core.training', 'bbpose_ros.core.synth',
               'bbpose_ros.core.adaptation', 'bbpose_ros.core.add_object', 'bbpose_ros.cli',
               'bbpose_ros.bags')
    assert sorted(m for m in reached if any(_in(m, o) for o in offline)) == []
    assert 'bbpose_ros.core.pipeline.overlays' in reached
