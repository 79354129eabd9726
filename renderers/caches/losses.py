"""Training losses of the neural caches (tensor mode, shape (outputs, batch)).

The NIRC paper (Sec. 4.1) derives three: the variance-based L_V (Eq. 16), plain
L2 (Eq. 17) and the relative L2 it trains with (Eq. 18). In all three p_r is
absorbed by training on records drawn from the rendering distribution itself,
and the residual is measured in incident radiance (target minus the cache's
n_i), the BSDF factor f_r cos / p of Eq. 11 left out as it is in Eq. 18's
implementation; for a diffuse BSDF sampled by its cosine that factor is the
albedo, constant at a shading point, so L_V differs from Eq. 16 by a factor
per shading point only.

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
    """Eq. 17 (NIRC paper), the plain squared error, averaged over channels and batch
    (also the visibility caches' L2 loss)."""
    return dr.mean(dr.square(pred - target), axis=None)


def variance(pred: mi.TensorXf, target: mi.TensorXf, group_size: int) -> mi.TensorXf:
    """L_V, Eq. 16 (NIRC paper): (r - F_r)^2 averaged over channels and batch, where
    r = target - pred is one sample of the residual (Eq. 5) and F_r, its expectation
    at the shading point, is estimated by the mean of r over the record's group: the
    ``group_size`` consecutive records of the batch that share one shading point.

    F_r is detached. The gradient is still that of the groups' sample variance:
    d/dw sum_k (r_k - m)^2 = 2 sum_k (r_k - m)(dr_k/dw - dm/dw), and the dm/dw term
    vanishes because sum_k (r_k - m) = 0. The minimiser is any cache whose residual
    is constant at each shading point (Sec. 4.1: "many solutions for any possible
    shift value").
    """
    residual = target - pred
    flat = dr.detach(residual.array)
    # Row-major (outputs, batch) with batch a multiple of group_size: a group's
    # records are group_size consecutive entries of each output's row.
    group_mean = dr.block_sum(flat, group_size) / group_size
    index = dr.arange(mi.UInt32, dr.width(flat)) // group_size
    offset = mi.TensorXf(dr.gather(mi.Float, group_mean, index), residual.shape)
    return dr.mean(dr.square(residual - offset), axis=None)


def cache_loss(config: LossConfig, pred: mi.TensorXf, target: mi.TensorXf) -> mi.TensorXf:
    """The loss a :class:`LossConfig` describes, as a 0-d tensor."""
    if config.kind == "relative_l2":
        return relative_l2(pred, target, config.epsilon, config.relative_to)
    if config.kind == "variance":
        return variance(pred, target, config.group_size)
    return l2(pred, target)
