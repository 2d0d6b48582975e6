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
Self-training on the user's scene: the pipeline teaches itself from unlabelled real frames.

Data flows one way: recorded frames (``frames``) -> the teacher's careful poses
(``teacher``) -> the labels it trusts (``selection``) -> a pseudo-labelled training set
(``label_set``) -> the students that learn from it (``students``); ``adapt_stages`` runs
them into an output folder the node loads. Nothing here reads ground truth. The sibling
of ``add_object`` (renders of a new object instead of a recording): both fit output layers
through ``training.head_fitting`` and write their graphs through ``training.quantization``.
"""
