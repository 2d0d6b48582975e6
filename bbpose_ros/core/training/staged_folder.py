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
An output folder built by stages, each written whole, so that a rerun resumes.

``bbpose add-object`` and ``bbpose adapt`` both work this way: every stage writes one file
or folder atomically, a stage whose output exists is skipped (a stopped run resumes at the
first missing one), ``inputs.json`` records what the folder was made from (a rerun with
other inputs is refused rather than mixing two runs' files) and ``report.json`` collects
the seconds of each stage, the total and the peak memory.
"""

from collections.abc import Callable, Mapping
import json
from pathlib import Path
import resource
import time
from typing import Any

from bbpose_ros.core.util.errors import InputError
from bbpose_ros.core.util.files import write_json_atomic


class StagedFolder:
    """
    The output folder of a staged run and its ``report.json``.

    Args:
        out: the folder (created).
        log: callable(str) for one line per stage.

    Attributes:
        report: the report, read back from ``report.json`` on a rerun; ``seconds`` holds
            each stage's time.

    """

    def __init__(self, out: Path | str, log: Callable[[str], None] = print) -> None:
        self.out, self.log = Path(out), log
        self.out.mkdir(parents=True, exist_ok=True)
        path = self.out / 'report.json'
        self.report: dict[str, Any] = json.loads(path.read_text()) if path.is_file() else {}
        self.report.setdefault('seconds', {})

    def check_inputs(self, inputs: Mapping[str, Any]) -> None:
        """
        Write ``inputs.json``, or refuse a folder made from other inputs.

        Raises:
            InputError: naming the inputs that differ from the folder's.

        """
        inputs = json.loads(json.dumps(inputs))     # tuples as JSON lists, as read back
        path = self.out / 'inputs.json'
        if path.is_file():
            before = json.loads(path.read_text())
            changed = sorted(k for k in set(before) | set(inputs)
                             if before.get(k) != inputs.get(k))
            if changed:
                raise InputError(f'{self.out} was made from other inputs ({", ".join(changed)} '
                                 f'differ, {path}); choose a new --out')
        write_json_atomic(path, inputs)

    def stage(self, name: str, work: Callable[[], None], output: Path | None) -> None:
        """Run ``work()`` unless ``output`` exists (None: always); time it into the report."""
        if output is not None and Path(output).exists():
            self.log(f'[{name}] done before: {output}')
            return
        self.log(f'[{name}] ...')
        start = time.monotonic()
        work()
        self.report['seconds'][name] = round(time.monotonic() - start, 1)
        self.save()

    def save(self) -> None:
        """Write ``report.json``."""
        write_json_atomic(self.out / 'report.json', self.report)

    def finish(self) -> dict[str, Any]:
        """Add the total seconds and the peak memory (MB, worker processes included); save."""
        seconds = self.report['seconds']
        seconds['total'] = round(sum(v for k, v in seconds.items() if k != 'total'), 1)
        self.report['peak_rss_mb'] = round(max(
            resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF,
                                                          resource.RUSAGE_CHILDREN)) / 1024)
        self.save()
        return self.report
