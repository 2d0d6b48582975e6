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
One new object taught to the shipped networks from its mesh alone (``bbpose add-object``).

Data flows one way: the checked mesh and its symmetries
(``add_object_settings.AddedObject``) -> a BOP dataset with the known objects and the new
one -> renders of it -> each network's new rows, fitted on cached features with everything
else frozen (``training.object_rows``) -> int8 graphs and a preview; ``add_object_stages``
runs them into an output folder the node loads. The sibling of ``adaptation`` (a
recording's frames instead of renders): both fit output layers through
``training.head_fitting`` and write their graphs through ``training.quantization``.
"""
