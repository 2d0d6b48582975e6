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
Parameter verdicts: a run-time set judged once, then answered.

rclpy calls the pre-set callback first, then checks the values against the descriptors
(refusing there without calling the on-set callback), then the on-set callback. So the
pre-set callback (``ParameterVerdicts.before_set``) judges the set, and logs and counts a
refusal (``parameters_refused``); the on-set callback (``on_set``) answers with that
verdict and hands the ``pipeline`` changes of an accepted set to the rebuild thread. A set
of a parameter the node does not have is refused naming it (``check_declared``).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter

from bbpose_ros.core.data.models import bop_object_ids, names_source
from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.core.util.errors import InputError
from bbpose_ros.ros.params import check_value, checked_options, parameter_values, PARAMETERS
from bbpose_ros.ros.rebuild import PipelineRebuilder
from bbpose_ros.ros.throttle import ProblemLog


@dataclass(frozen=True)
class SetVerdict:
    """
    What a parameter set comes to, judged once (``ParameterVerdicts.judge``).

    Attributes:
        names: the parameters set, in order.
        reason: why the set is refused, or None.
        changes: {name: value} of the ``pipeline`` parameters a rebuild must take.
        options: the PipelineOptions of every parameter's value with the set's.

    """

    names: tuple[str, ...]
    reason: str | None
    changes: dict[str, Any] = field(default_factory=dict)
    options: PipelineOptions | None = None


class UnknownParameterError(ParameterNotDeclaredException):
    """A set of a parameter the node does not have; its text is the reason given back."""

    def __init__(self, reason: str) -> None:
        Exception.__init__(self, reason)    # rclpy's own text names no parameter


class ParameterVerdicts:
    """
    Judges and answers the parameter sets of a node.

    Args:
        node: the node whose parameters are set.
        rebuilder: holds the current config; takes an accepted set's pipeline changes.
        problems: counts and logs a refusal.
        add_objects: creates the pose publishers of the object names a set adds.
        state: returns the node's lifecycle state, named in a refusal.

    """

    def __init__(self, node: Node, rebuilder: PipelineRebuilder, problems: ProblemLog,
                 add_objects: Callable[[Sequence[str]], None],
                 state: Callable[[], str]) -> None:
        self._node = node
        self._rebuilder = rebuilder
        self._problems = problems
        self._add_objects = add_objects
        self._state = state
        self._verdict: SetVerdict | None = None   # of the set rclpy is making

    def before_set(self, parameters: list[Parameter]) -> list[Parameter]:
        """Judge a set once, log and count a refusal; ``on_set`` gives the verdict."""
        self._verdict = self.judge(parameters)
        if self._verdict.reason is not None:
            self._problems.warn('parameters_refused', ' '.join(p.name for p in parameters),
                                f'set refused: {self._verdict.reason}')
        return parameters

    def on_set(self, parameters: list[Parameter]) -> SetParametersResult:
        """Answer a set with its verdict; hand ``pipeline`` changes to the rebuild thread."""
        verdict, self._verdict = self._verdict, None
        if verdict is None or verdict.names != tuple(p.name for p in parameters):
            verdict = self.judge(parameters)       # not seen by the pre-set callback
        if verdict.reason is not None:
            return SetParametersResult(successful=False, reason=verdict.reason)
        if verdict.changes:
            self._add_objects(verdict.changes.get('objects', ()))
            self._rebuilder.request(verdict.changes, verdict.options)
        return SetParametersResult(successful=True)

    def check_declared(self, parameters: list[Parameter]) -> None:
        """Raise UnknownParameterError naming a parameter of the set the node does not have."""
        for parameter in parameters:
            if not self._node.has_parameter(parameter.name):
                raise UnknownParameterError(self.refusal(parameter))

    def judge(self, parameters: list[Parameter]) -> SetVerdict:
        """
        Check a set: each value, then all values with the new ones as PipelineOptions.

        Everything that can be checked without building is checked here (the object names
        against the dataset too), so a set that is accepted rarely fails to build.
        """
        names = tuple(p.name for p in parameters)
        for parameter in parameters:
            reason = self.refusal(parameter)
            if reason is not None:
                return SetVerdict(names, reason)
        new = {p.name: p.value for p in parameters if p.name in PARAMETERS}
        try:
            options = checked_options({**parameter_values(self._node), **new})
            self._check_objects(new.get('objects'))
        except InputError as err:
            return SetVerdict(names, str(err))
        changes = self._rebuilder.needed({name: value for name, value in new.items()
                                          if PARAMETERS[name].applies == 'pipeline'})
        return SetVerdict(names, None, changes, options)

    def refusal(self, parameter: Parameter) -> str | None:
        """Return why ``parameter``'s new value is refused now, or None."""
        if not self._node.has_parameter(parameter.name):
            return (f'parameter {parameter.name} does not exist: {self._node.get_name()} has '
                    f'{", ".join(PARAMETERS)}')
        spec = PARAMETERS.get(parameter.name)
        if spec is None:       # rclpy's own (use_sim_time)
            return None
        if spec.applies == 'start':
            return f'parameter {parameter.name} is read once at start (read-only)'
        if spec.applies == 'configure' and self._rebuilder.config is not None:
            return (f'parameter {parameter.name} is read by the configure transition: set it '
                    f'while the node is unconfigured (it is {self._state()})')
        try:
            check_value(parameter.name, parameter.value)
        except InputError as err:
            return str(err)
        return None

    def _check_objects(self, names: Sequence[str] | None) -> None:
        """Raise InputError when object ``names`` (None: not set) are not in the dataset."""
        config = self._rebuilder.config
        if names is None or config is None:
            return
        known = bop_object_ids(config.dataset_dir)
        unknown = [name for name in names if name not in known]
        if unknown:
            raise InputError(f'parameter objects: {", ".join(unknown)} not in '
                             f'{names_source(config.dataset_dir)} (known: '
                             f'{", ".join(known)})')
