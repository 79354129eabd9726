"""Training losses of the neural caches (tensor mode, shape (outputs, batch)).

The relative L2 loss is Eq. 18 of the NIRC paper,

    L_rel^2 = (f(x) - f_c(x, w))^2 / (p_r(x) (sg(f_c(x, w)^2) + eps)),

where sg() stops the gradient and p_r is absorbed by training on records
drawn from the rendering distribution itself (as NRC does). Dividing by the
(detached) squared prediction makes the loss scale-invariant, so dark regions
weigh as much as bright ones, and the detach keeps the minimiser unbiased: the
gradient is that of a weighted L2 with weights 1/(sg(pred)^2 + eps).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from renderers.caches.config import LossConfig

#: Rec. 709 luminance weights (tiny-cuda-nn's RelativeL2Luminance uses these).
LUMINANCE = (0.2126, 0.7152, 0.0722)


def luminance(rgb: mi.TensorXf) -> mi.TensorXf:
    """Luminance of a (3, N) tensor as a (1, N) tensor."""
    lum = rgb[0] * LUMINANCE[0] + rgb[1] * LUMINANCE[1] + rgb[2] * LUMINANCE[2]
    return dr.reshape(mi.TensorXf, lum, (1, rgb.shape[1]))


def relative_l2(pred: mi.TensorXf, target: mi.TensorXf, epsilon: float,
                relative_to: str) -> mi.TensorXf:
    """Eq. 18 (NIRC paper), averaged over channels and batch.

    ``relative_to='luminance'`` normalises all channels by the prediction's
    luminance (the authors' code), ``'channel'`` each channel by itself.
    """
    scale = luminance(pred) if relative_to == "luminance" else pred
    denom = dr.square(dr.detach(scale)) + epsilon
    return dr.mean(dr.square(pred - target) / denom, axis=None)


def l2(pred: mi.TensorXf, target: mi.TensorXf) -> mi.TensorXf:
    """Plain squared error, averaged over channels and batch (NVC, L2 loss)."""
    return dr.mean(dr.square(pred - target), axis=None)


def cache_loss(config: LossConfig, pred: mi.TensorXf, target: mi.TensorXf) -> mi.TensorXf:
    """The loss a :class:`LossConfig` describes, as a 0-d tensor."""
    if config.kind == "relative_l2":
        return relative_l2(pred, target, config.epsilon, config.relative_to)
    return l2(pred, target)
