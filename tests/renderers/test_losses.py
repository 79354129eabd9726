"""The NIRC paper's training losses (Sec. 4.1): L_V (Eq. 16), L2 (Eq. 17), relative L2
(Eq. 18). Each loss's value is checked against the equation written out in numpy, its
gradient against central differences of that value, and L_V's minimiser on a toy
integral where the paper says what it is; planted wrong formulas are rejected."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from renderers.caches import losses
from renderers.methods.nirc import NIRCParams

pytestmark = pytest.mark.usefixtures("mi")

GROUP = 4
LossFn = Callable[[Any, Any], Any]


def eq16(pred: np.ndarray, target: np.ndarray) -> float:
    """(r - F_r)^2, F_r the mean residual of each group of GROUP consecutive records."""
    r = (target - pred).reshape(pred.shape[0], -1, GROUP)
    return float(np.mean((r - r.mean(axis=-1, keepdims=True)) ** 2))


def eq17(pred: np.ndarray, target: np.ndarray) -> float:
    return float(np.mean((target - pred) ** 2))


def eq18(pred: np.ndarray, target: np.ndarray) -> float:
    return float(np.mean((target - pred) ** 2 / (pred ** 2 + 0.01)))


IMPLEMENTED: dict[str, tuple[LossFn, Callable[[np.ndarray, np.ndarray], float]]] = {
    "variance": (lambda p, t: losses.variance(p, t, GROUP), eq16),
    "l2": (losses.l2, eq17),
    "relative_l2": (lambda p, t: losses.relative_l2(p, t, 0.01, "channel"), eq18),
}


def batch(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return (rng.uniform(0.2, 2.0, (3, 4 * GROUP)), rng.uniform(0.0, 3.0, (3, 4 * GROUP)))


def check(loss: LossFn, formula: Callable[[np.ndarray, np.ndarray], float],
          seed: int = 1) -> None:
    """The loss's value is ``formula``'s, and its gradient (the detached parts included:
    F_r, sg(f_c)) matches central differences of the formula, except for Eq. 18, whose
    sg() makes the gradient that of the weighted L2 with frozen weights."""
    pred_np, target_np = batch(seed)
    pred, target = mi.TensorXf(pred_np.astype(np.float32)), mi.TensorXf(target_np)
    dr.enable_grad(pred)
    value = loss(pred, target)
    dr.backward(value)
    grad = dr.grad(pred).numpy()
    assert float(value.array[0]) == pytest.approx(formula(pred_np, target_np), rel=1e-5)
    weights = 1.0 / (pred_np ** 2 + 0.01) if formula is eq18 else None
    step = 1e-4
    for index in np.ndindex(pred_np.shape):
        up, down = pred_np.copy(), pred_np.copy()
        up[index] += step
        down[index] -= step
        if weights is None:
            numeric = (formula(up, target_np) - formula(down, target_np)) / (2 * step)
        else:  # sg(f_c): differentiate with the weights held at pred
            numeric = float(np.mean(weights * ((target_np - up) ** 2 - (target_np - down) ** 2))
                            / (2 * step))
        assert grad[index] == pytest.approx(numeric, rel=2e-3, abs=1e-6), index


@pytest.mark.parametrize("kind", sorted(IMPLEMENTED))
def test_a_loss_is_its_equation_and_its_gradient_that_of_the_equation(kind: str) -> None:
    check(*IMPLEMENTED[kind])


def test_planted_wrong_formulas_are_rejected() -> None:
    # F_r over the whole batch instead of each shading point's group.
    whole_batch = lambda p, t: losses.variance(p, t, 4 * GROUP)  # noqa: E731
    # Eq. 18 without sg(): another gradient.
    no_stop = lambda p, t: dr.mean(dr.square(p - t) / (dr.square(p) + 0.01), axis=None)  # noqa: E731
    for loss, formula in ((whole_batch, eq16), (losses.l2, eq16), (no_stop, eq18)):
        with pytest.raises(AssertionError):
            check(loss, formula)


def fit_line(loss: LossFn, steps: int = 150, seed: int = 3) -> tuple[float, float]:
    """Gradient descent on f_c(x) = w0 + w1 x against f(x) = 2 + 3 x, x ~ U(0, 1) (p_r = 1),
    from w = (0, 0); every step draws 64 groups of GROUP samples (F_r's estimate)."""
    rng = np.random.default_rng(seed)
    w = np.zeros(2)
    for _ in range(steps):
        x = rng.uniform(0.0, 1.0, (1, 64 * GROUP))
        # Opaque: one kernel for every step, not one per value of w.
        w0, w1 = dr.opaque(mi.Float, w[0]), dr.opaque(mi.Float, w[1])
        dr.enable_grad(w0, w1)
        xs = mi.TensorXf(x.astype(np.float32))
        pred = mi.TensorXf(dr.ones(mi.Float, x.size) * w0, xs.shape) + xs * mi.TensorXf(
            dr.ones(mi.Float, x.size) * w1, xs.shape)
        dr.backward(loss(pred, mi.TensorXf((2 + 3 * x).astype(np.float32))))
        w -= 0.5 * np.array([dr.grad(w0)[0], dr.grad(w1)[0]])
    return float(w[0]), float(w[1])


def test_lv_fits_the_shape_and_leaves_the_shift_where_it_started() -> None:
    # Sec. 4.1: L_V's minimisers are the caches off f by any constant shift: the slope
    # is learned, the offset gets no gradient and stays at its start (0), where L2
    # learns both. A planted L_V without F_r (that is, L2) moves the offset.
    w0, w1 = fit_line(lambda p, t: losses.variance(p, t, GROUP))
    assert w1 == pytest.approx(3.0, abs=0.05)
    assert abs(w0) < 1e-4
    l2_w0, l2_w1 = fit_line(losses.l2)
    assert (l2_w0, l2_w1) == pytest.approx((2.0, 3.0), abs=0.1)
    assert abs(l2_w0 - w0) > 1.0   # the check above rejects L2 as L_V


def test_the_loss_parameter_sets_the_cache_loss_and_refuses_what_lv_cannot_train() -> None:
    assert NIRCParams().cache_config().loss.kind == "relative_l2"
    assert NIRCParams(loss="l2").cache_config().loss.kind == "l2"
    lv = NIRCParams(loss="variance", record_depth=1).cache_config().loss
    assert (lv.kind, lv.records_per_point) == ("variance", lv.group_size)
    with pytest.raises(ValueError, match="record_depth=1"):
        NIRCParams(loss="variance")
    with pytest.raises(ValueError, match="contradicts"):
        NIRCParams(loss="l2", cache={"loss": {"kind": "variance"}})
