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
The paper's q-normalization layer and Dot Product Loss, extended to symmetries and hypotheses.

The Dot Product Loss is taken against the best of a symmetric object's equivalent ground
truths (one candidate: the paper's loss), and winner-takes-all over several hypotheses.

Quaternions here are (w, x, y, z) = (q0, q1, q2, q3), the paper's order, along the last
axis of (B, 4) or (B, H, 4) tensors.
Ground truths live on the q0 >= 0 hemisphere (the paper's q+ rule).
"""

import torch
from torch import nn
import torch.nn.functional as F


class QNormalization(nn.Module):
    """
    q-normalization layer: q_i = Q_i / sqrt(sum_j Q_j^2), over the last axis.

    Autograd's backward equals the paper's dq_j/dQ_i = (delta_ij - q_i q_j) / A with
    A = ||Q|| (checked in test/test_qnet.py). ``eps`` only guards a zero vector.
    """

    def __init__(self, eps: float = 1e-8) -> None:
        super().__init__()
        self.eps = eps

    def forward(self, raw: torch.Tensor) -> torch.Tensor:
        """Map (..., 4) raw outputs Q to unit quaternions q."""
        return raw / raw.norm(dim=-1, keepdim=True).clamp_min(self.eps)


def symmetric_dot_product_loss(q_pred: torch.Tensor, q_candidates: torch.Tensor,
                               valid: torch.Tensor) -> torch.Tensor:
    """
    Dot Product Loss (1 - q_pred . q) / 2 against the best of several equivalent ground truths.

    Args:
        q_pred: (B, 4) predicted quaternions (wxyz).
        q_candidates: (B, K, 4) ground truth composed with each symmetry of its object
            (identity first), each on the q0 >= 0 hemisphere.
        valid: (B, K) bool, False for padding (objects with fewer symmetries).

    Returns:
        (B,) per-sample loss: the minimum over the valid candidates.

    """
    losses = 0.5 * (1.0 - torch.einsum('bd,bkd->bk', q_pred, q_candidates))
    return losses.masked_fill(~valid, float('inf')).min(dim=1).values


def multi_hypothesis_loss(q_hypotheses: torch.Tensor, scores: torch.Tensor,
                          q_candidates: torch.Tensor, valid: torch.Tensor, relax: float = 0.05,
                          score_weight: float = 0.1) -> torch.Tensor:
    """
    Relaxed winner-takes-all loss of several hypotheses (Rupprecht et al., ICCV 2017).

    The best hypothesis (lowest ``symmetric_dot_product_loss``) gets weight 1 - ``relax``,
    the others share ``relax`` (so that none is left untrained); the scores learn by
    cross-entropy which hypothesis is the best, weighted by ``score_weight``.

    Args:
        q_hypotheses: (B, H, 4) predicted quaternions (wxyz), H >= 2.
        scores: (B, H) logits of the hypotheses.
        q_candidates, valid: as in ``symmetric_dot_product_loss``.
        relax: weight shared by the H - 1 other hypotheses.
        score_weight: weight of the scores' cross-entropy.

    Returns:
        (B,) per-sample loss.

    """
    batch, count = q_hypotheses.shape[:2]
    if count < 2:
        raise ValueError(f'winner-takes-all needs at least 2 hypotheses, got {count}')
    losses = symmetric_dot_product_loss(q_hypotheses.reshape(-1, 4),
                                        q_candidates.repeat_interleave(count, dim=0),
                                        valid.repeat_interleave(count, dim=0))
    losses = losses.view(batch, count)
    best = losses.detach().argmin(dim=1)
    weights = torch.full_like(losses, relax / (count - 1))
    weights.scatter_(1, best.unsqueeze(1), 1.0 - relax)
    return (weights * losses).sum(dim=1) + \
        score_weight * F.cross_entropy(scores, best, reduction='none')
