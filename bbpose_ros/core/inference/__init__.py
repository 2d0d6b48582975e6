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
Inference plumbing beside the stages: settings, weight files, network backends, int8 graphs.

``options.PipelineOptions`` states every run-time setting (a leaf: it imports nothing
heavy); ``weights`` reads and checks the weight files, ``backends`` runs a network on
onnxruntime or torch, ``int8_graphs`` finds and checks the quantised graphs. The stages of
``core.pipeline`` use these, and ``pipeline.loader`` builds the stages from a
PipelineOptions; nothing here imports the stages.
"""
