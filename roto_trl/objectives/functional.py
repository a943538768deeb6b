"""The objectives' maths as small pure functions on tensors (unit-tested by hand)."""

from __future__ import annotations

import torch
import torch.nn.functional as F

AUTO_POS_WEIGHT_MAX = 100.0


def auto_pos_weight(target: torch.Tensor, max_weight: float = AUTO_POS_WEIGHT_MAX) -> torch.Tensor:
    """Inverse contact rate of ``target`` (0/1), clamped to [1, ``max_weight``]: rare contacts weigh more.

    A minibatch without contacts gets ``max_weight``.
    """
    rate = target.float().mean()
    return (1.0 / rate.clamp_min(1.0 / max_weight)).clamp(1.0, max_weight).detach()


def contact_bce(logits: torch.Tensor, target: torch.Tensor, pos_weight: float | torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy on logits, positives weighted by ``pos_weight``, mean over all elements.

    Per element: ``-(w * y * log(sigmoid(x)) + (1 - y) * log(1 - sigmoid(x)))``.
    """
    weight = torch.as_tensor(pos_weight, dtype=logits.dtype, device=logits.device)
    return F.binary_cross_entropy_with_logits(logits, target.to(logits.dtype), pos_weight=weight)


def latent_mse(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error between predicted and target latents (``target`` gets no gradient)."""
    return (prediction - target.detach()).square().mean()


@torch.no_grad()
def contact_confusion(logits: torch.Tensor, target: torch.Tensor) -> dict[str, torch.Tensor]:
    """Rates of predicted contacts (logit > 0, i.e. probability > 0.5) against true ones.

    Returns ``tpr, fpr, fnr, tnr, accuracy, precision`` (NaN where undefined: no positives for
    TPR/FNR, no negatives for FPR/TNR, no predicted positives for precision).
    """
    pred = logits > 0
    true = target > 0.5
    tp = (pred & true).sum().float()
    fp = (pred & ~true).sum().float()
    fn = (~pred & true).sum().float()
    tn = (~pred & ~true).sum().float()
    nan = torch.tensor(float("nan"), device=logits.device)

    def ratio(a, b):
        return a / b if b > 0 else nan

    return {
        "tpr": ratio(tp, tp + fn),
        "fpr": ratio(fp, fp + tn),
        "fnr": ratio(fn, tp + fn),
        "tnr": ratio(tn, fp + tn),
        "accuracy": (tp + tn) / (tp + fp + fn + tn),
        "precision": ratio(tp, tp + fp),
    }


def rollout_latents(forward_model, z0: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Predict latents autoregressively: ẑ_{t+1} = f(z_t, a_t), ẑ_{t+i+1} = f(ẑ_{t+i}, a_{t+i}).

    Args:
        forward_model: callable on ``cat([z, a], -1)`` -> next latent.
        z0: ``[B, Z]`` latent of the first observation.
        actions: ``[B, n - 1, A]`` actions taken at steps t .. t+n-2.

    Returns:
        ``[B, n - 1, Z]`` predicted latents of steps t+1 .. t+n-1.
    """
    z, out = z0, []
    for i in range(actions.shape[1]):
        z = forward_model(torch.cat([z, actions[:, i]], dim=-1))
        out.append(z)
    return torch.stack(out, dim=1)
