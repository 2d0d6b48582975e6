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
The node's current NodeConfig and NodePipeline, and their rebuild off the executor thread.

A run-time set of a ``pipeline`` parameter hands its changes to ``PipelineRebuilder``; one
rebuild thread builds the pipeline of the changed config while the node keeps answering
frames with the pipeline it has, then swaps config and pipeline in together. Changes that
arrive during a build are queued for the next one. A configure or a cleanup starts a new
generation: a build begun before it is thrown away when it ends. A build that fails hands
the values the pipeline has back to ``set_back``, so the parameters say what runs.
"""

from collections.abc import Callable
import threading
from typing import Any

from bbpose_ros.core.inference.options import PipelineOptions
from bbpose_ros.ros.node_pipeline import NodePipeline, stop_background
from bbpose_ros.ros.params import NodeConfig


class PipelineRebuilder:
    """
    Holds the (NodeConfig, NodePipeline) pair and rebuilds it for parameter changes.

    Thread-safe: the executor thread configures, cleans up and requests; the worker reads
    ``pipeline`` once per frame; the rebuild thread swaps.

    Args:
        build: makes the NodePipeline of a NodeConfig; raises on failure.
        set_back: sets parameters back ({name: value}) after a failed build.
        log: gets a line when a rebuild starts and when it is swapped in.
        refuse: gets (names, text) when a rebuild failed and its values are set back.
        reason: turns a build's exception into the reason given.

    """

    def __init__(self, build: Callable[[NodeConfig], NodePipeline],
                 set_back: Callable[[dict[str, Any]], None], log: Callable[[str], None],
                 refuse: Callable[[str, str], None],
                 reason: Callable[[BaseException], str] = str) -> None:
        self._build = build
        self._set_back = set_back
        self._log = log
        self._refuse = refuse
        self._reason = reason
        self._lock = threading.Lock()
        self._config: NodeConfig | None = None
        self._pipeline: NodePipeline | None = None
        self._pending: dict[str, Any] = {}
        self._options: PipelineOptions | None = None      # those of the pending changes
        self._thread: threading.Thread | None = None
        self._generation = 0              # configures and cleanups so far

    @property
    def config(self) -> NodeConfig | None:
        """Return the config the current pipeline was built from (None: unconfigured)."""
        return self._config

    @property
    def pipeline(self) -> NodePipeline | None:
        """Return the NodePipeline in use (None: unconfigured)."""
        return self._pipeline

    def install(self, config: NodeConfig, pipeline: NodePipeline) -> None:
        """Take a configure's config and pipeline; a build under way is thrown away."""
        with self._lock:
            self._config, self._pipeline = config, pipeline
            self._generation += 1

    def release(self) -> None:
        """Forget config and pipeline (cleanup); queued changes and a build under way too."""
        with self._lock:
            self._config = self._pipeline = None
            self._pending = {}
            self._generation += 1

    def needed(self, changes: dict[str, Any]) -> dict[str, Any]:
        """Return the ``changes`` a rebuild must make: values the pipeline has need none."""
        with self._lock:
            if self._config is None:
                return {}
            return {name: value for name, value in changes.items()
                    if value != self._config.values[name] or name in self._pending}

    def request(self, changes: dict[str, Any], options: PipelineOptions) -> None:
        """
        Queue ``changes`` ({name: value}) for the rebuild thread; start it unless running.

        ``options`` are the checked PipelineOptions of every parameter's value with these
        changes (and those queued before): the next build's.
        """
        with self._lock:
            self._pending.update(changes)
            self._options = options
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name='bbpose_rebuild',
                                                daemon=True)
                self._thread.start()

    def _run(self) -> None:
        """Rebuild thread: build the pipeline with the queued changes and swap it in."""
        while True:
            with self._lock:
                changes, self._pending = self._pending, {}
                if not changes or self._config is None:
                    self._thread = None
                    return
                config = self._config.updated(changes, self._options)
                generation = self._generation
            self._log(f'rebuilding the pipeline for {", ".join(changes)}; frames are '
                      'answered with the current one meanwhile')
            try:
                pipeline = self._build(config)
            except Exception as err:  # noqa: B902 - a failed rebuild sets the values back
                self._undo(changes, self._reason(err))
                continue
            with self._lock:
                if generation != self._generation:    # cleaned up or reconfigured meanwhile
                    stop_background(pipeline, for_good=True)
                    continue
                self._config, self._pipeline, old = config, pipeline, self._pipeline
            if old is not None:   # a frame in hand on it ends without a background job
                stop_background(old, for_good=True)
            self._log(f'pipeline rebuilt for {", ".join(changes)}')

    def _undo(self, changes: dict[str, Any], reason: str) -> None:
        """Set the parameters of a failed rebuild back to the values the pipeline has."""
        self._refuse(' '.join(changes), f'rebuild for {", ".join(changes)} failed, the '
                     f'values are set back: {reason}')
        with self._lock:
            config = self._config
            for name in changes:
                self._pending.pop(name, None)
        if config is not None:
            self._set_back({name: config.values[name] for name in changes})
