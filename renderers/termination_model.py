"""A discrete model of path termination into a radiance cache: a sampling tree whose
estimators are evaluated exactly, by enumerating every path.

The variance-trading paper ([VTT24], docs/references.md) validates its two
termination rules on such trees (their Fig. 4 and 5). The trees
themselves are only drawn there, so this module states one of its own in the same
spirit (:func:`binary_tree`): leaves emit one unit, each inner node chooses its left
child with probability 0.9, and for the MSE experiments inner nodes carry biased cache
values. Small trees (depth <= 4) have few enough paths for exact expectations and for
an exhaustive search over termination decisions, so the greedy rules can be compared
with the optimum. The quantities (names after the paper's Sec. 3 and 4.1):

==========================  ==========================================================
``value(n)``                V(n) = Le(n) + R(n): what a path arriving at n gathers from
                            n on, its emission plus the reflected radiance
``reflected(n)``            R(n) = sum_c f_c V(c), what the cache at n stands for
``cache(n)``                rc(n) = R(n) + bias(n): the cache's (maybe biased) value
``local_variance(n)``       V E[g_n^surf | x_{n+1}] = Var_c[(f_c / p_c) V(c)] (Eq. 1)
``local_bias(n)``           rc(n) - R(n), the term of Eq. 3 before the prefix
``deferred_bias(n)``        E_c[(f_c / p_c)^2 (rc(c) - R(c))^2]: the squared local bias
                            one vertex later, as the MSE rule needs it (Sec. 4.3)
==========================  ==========================================================

A path is walked as a renderer walks it: arriving at node n with prefix weight g
(g_n^pre, the product of f / p so far) it gathers g Le(n), then asks a termination
rule for a *continuation weight* a in [0, 1] given the path's state (g and the sum S
of the prefixed local variances P_j = g_j^2 V E[...] of the vertices it continued
from). a = 1 continues; a = 0 ends the path with g rc(n); 0 < a < 1 blends the cache
with one more segment and ends there (Eq. 5):

    g [(1 - a) rc(n) + a (f_c / p_c) (Le(c) + rc(c))]

so the blend weight scales the direct light at the next vertex as well as the cache's
reflected radiance there.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import TypeVar

import drjit as dr

T = TypeVar("T")

#: Floor of a local variance divided by (a zero P only occurs where S + P <= t fails
#: because S alone is over t: then alpha is 0 whatever P is).
_TINY = 1e-30

#: The probability of choosing the left child (the paper's trees: 90 %).
LEFT_PROBABILITY = 0.9

#: Inner nodes' cache biases of the MSE experiments (Fig. 5's kind of tree, depth 4;
#: docs/variance_trading.md, "The discrete model").
EXAMPLE_BIASES = {"": 0.3, "L": 0.1, "R": -0.2, "LL": 0.05, "LR": 0.3, "RL": -0.1, "RR": 0.0,
                  "LLL": 0.02, "LLR": 0.1, "LRL": -0.05, "LRR": 0.2, "RLL": 0.0, "RLR": 0.1,
                  "RRL": -0.1, "RRR": 0.05}


@dataclass(frozen=True)
class Node:
    """One vertex of the tree: ``name`` is its path from the root ("", "L", "LR", ...);
    ``children`` are (child, f, p): the transport weight f of the edge and the
    probability p of choosing it (the p of an inner node sum to one)."""

    name: str
    emission: float = 0.0
    bias: float = 0.0
    children: tuple[tuple[Node, float, float], ...] = ()

    @property
    def is_leaf(self) -> bool:
        return not self.children

    @cached_property
    def reflected(self) -> float:
        return sum(weight * child.value for child, weight, _ in self.children)

    @cached_property
    def value(self) -> float:
        return self.emission + self.reflected

    @property
    def cache(self) -> float:
        """rc(n): a leaf reflects nothing, so its cache is exact (zero)."""
        return self.reflected + (0.0 if self.is_leaf else self.bias)

    @cached_property
    def local_variance(self) -> float:
        """Var over the next vertex of E[g^surf | x_next] = (f / p) V(child) (Eq. 1)."""
        second = sum(p * (f / p * child.value) ** 2 for child, f, p in self.children)
        return max(second - self.reflected ** 2, 0.0)

    @property
    def local_bias(self) -> float:
        return self.cache - self.reflected

    @cached_property
    def deferred_bias(self) -> float:
        """E over the next vertex of its squared local bias, prefix weight f / p included."""
        return sum(p * (f / p * child.local_bias) ** 2 for child, f, p in self.children)

    def nodes(self) -> Iterator[Node]:
        yield self
        for child, _, _ in self.children:
            yield from child.nodes()


def binary_tree(depth: int, weight: float = 0.45, biases: Mapping[str, float] | None = None,
                left_probability: float = LEFT_PROBABILITY) -> Node:
    """A full binary tree of ``depth`` levels below the root: leaves emit one unit, both
    edges of an inner node carry the transport weight ``weight`` (an albedo of
    2 ``weight``), the left one is chosen with ``left_probability``; ``biases`` gives
    inner nodes' cache biases by name (missing: exact caches)."""
    biases = dict(biases or {})

    def build(name: str) -> Node:
        if len(name) == depth:
            return Node(name, emission=1.0)
        return Node(name, bias=biases.get(name, 0.0),
                    children=((build(name + "L"), weight, left_probability),
                              (build(name + "R"), weight, 1.0 - left_probability)))

    tree = build("")
    unknown = set(biases) - {node.name for node in tree.nodes() if not node.is_leaf}
    if unknown:
        raise ValueError(f"no inner nodes named {sorted(unknown)} in a tree of depth {depth}")
    return tree


# ---- Decision formulas, shared with the renderer ------------------------------------
#
# The policies of renderers/integrators/termination (var_bound.py, mse_min.py) call
# these same functions on Dr.Jit arrays, one lane per path, so the model's tests cover
# the renderer's decisions. They use only operations that Dr.Jit defines for Python
# floats and arrays alike.

def variance_bound_weight(path_variance: T, local: T, threshold: T | float) -> T:
    """The continuation weight of variance bounding ([VTT24] Sec. 4.2): 1 while the
    path variance S plus this vertex's prefixed local variance P stays at or under t
    (l(X) = argmax_l sum_{j<l} P_j <= t), else the blend weight of Eq. 5,
    alpha = sqrt((t - S) / P), so that S + alpha^2 P = t (0 once S has reached t)."""
    within = path_variance + local <= threshold
    alpha = dr.sqrt(dr.maximum(threshold - path_variance, 0.0)
                    / dr.maximum(local, _TINY))
    return dr.select(within, 1.0, dr.minimum(alpha, 1.0))


def mse_min_terminates(path_variance: T, local: T, prefix_sq: T, local_bias_sq: T,
                       deferred_bias_sq: T, samples: float, margin: float,
                       clamp: float) -> T:
    """The greedy comparison of MSE minimization ([VTT24] Sec. 4.3, Eq. 4 split at this
    vertex): terminate when the current MSE, S / s + g^2 b^2, is at most ``margin``
    times the deferred MSE, (S + P) / s + g^2 min(d, clamp / margin b^2). S: path
    variance so far; P: this vertex's prefixed local variance; g^2: the squared prefix
    weight; b^2: the local squared bias; d: the deferred squared bias, E[(f / p)^2
    b_next^2] (the prefix weight of the next segment included). The reading of the
    margin and the clamp is this project's (docs/variance_trading.md)."""
    current = path_variance / samples + prefix_sq * local_bias_sq
    deferred_bias = dr.minimum(deferred_bias_sq, clamp / margin * local_bias_sq)
    deferred = (path_variance + local) / samples + prefix_sq * deferred_bias
    return current <= margin * deferred


# ---- Termination rules -------------------------------------------------------------

@dataclass(frozen=True)
class PathState:
    """What a rule may read at a vertex: the prefix weight g and the path variance S."""

    node: Node
    prefix_weight: float
    path_variance: float

    @property
    def prefixed_local_variance(self) -> float:
        return self.prefix_weight ** 2 * self.node.local_variance


#: A termination rule: the continuation weight in [0, 1] at a vertex.
Rule = Callable[[PathState], float]


def variance_bounding(threshold: float) -> Rule:
    """Continue while the path variance stays under ``threshold`` (Sec. 4.2,
    l(X) = argmax_l sum_{j<l} P_j <= t); at the vertex whose P_l would cross it, blend
    with alpha = sqrt((t - sum_{j<l} P_j) / P_l) (Eq. 5), so the path's variance
    reaches t exactly."""
    def rule(state: PathState) -> float:
        return float(variance_bound_weight(state.path_variance,
                                           state.prefixed_local_variance, threshold))
    return rule


@dataclass(frozen=True)
class MSEMinimizing:
    """The greedy rule of Sec. 4.3 for a sample target s: terminate when the current
    MSE, S / s + g^2 b^2 (b the local bias, Eq. 4), is at most ``margin`` times the
    deferred MSE, (S + P) / s + g^2 d (d the deferred squared bias).

    The paper gives the rule as pseudo-code in a figure, without the margin's value or
    an exact form of its clamp; this is this project's reading (docs/variance_trading.md):
    * the margin multiplies the whole deferred MSE, so the path variance S, which does
      not scale with the current throughput, no longer cancels from the comparison (the
      paper: "the prefix does not cancel entirely");
    * the deferred squared bias is clamped to ``clamp`` / ``margin`` times the local
      one, so that as s grows a biased cache is always deferred past (the paper: "clamp
      the deferred bias to 90 % below the local bias, also accounting for the margin
      factor")."""

    samples: float
    margin: float = 1.1
    clamp: float = 0.9

    def __call__(self, state: PathState) -> float:
        node = state.node
        stop = mse_min_terminates(state.path_variance, state.prefixed_local_variance,
                                  state.prefix_weight ** 2, node.local_bias ** 2,
                                  node.deferred_bias, self.samples, self.margin, self.clamp)
        return 0.0 if stop else 1.0


def frontier_rule(stops: frozenset[str]) -> Rule:
    """Terminate exactly at the named nodes (a fixed set of decisions, as the
    exhaustive search enumerates them)."""
    return lambda state: 0.0 if state.node.name in stops else 1.0


# ---- Exact evaluation --------------------------------------------------------------

@dataclass(frozen=True)
class Outcome:
    """One path's estimate and probability, where it stopped (its last full vertex),
    its length in vertices (the blended segment counted by its weight) and its path
    variance: the prefixed local variances it accumulated (the blended one by a^2)."""

    probability: float
    estimate: float
    stopped_at: str
    length: float
    path_variance: float


@dataclass(frozen=True)
class Evaluation:
    """Exact moments of a rule's one-sample estimator on a tree."""

    outcomes: tuple[Outcome, ...]
    truth: float

    @property
    def mean(self) -> float:
        return sum(o.probability * o.estimate for o in self.outcomes)

    @property
    def variance(self) -> float:
        second = sum(o.probability * o.estimate ** 2 for o in self.outcomes)
        return max(second - self.mean ** 2, 0.0)

    @property
    def bias(self) -> float:
        return self.mean - self.truth

    def mse(self, samples: float = 1.0) -> float:
        """MSE of the average of ``samples`` independent estimates: V / N + Bias^2."""
        return self.variance / samples + self.bias ** 2

    @property
    def expected_path_variance(self) -> float:
        """E[sum of the prefixed local variances a path accumulated] (Eq. 2)."""
        return sum(o.probability * o.path_variance for o in self.outcomes)

    @property
    def mean_length(self) -> float:
        return sum(o.probability * o.length for o in self.outcomes)


#: The blend at a path's last segment: (cache here, next vertex's emission, next
#: vertex's cache, f / p, a) -> the estimate after the prefix weight. Exposed so that
#: tests can plant wrong blends and see the checks reject them.
Blend = Callable[[float, float, float, float, float], float]


def blend(cache: float, next_emission: float, next_cache: float, ratio: float,
          weight: float) -> float:
    """Eq. 5's estimator: (1 - a) rc(x) + a (f / p) (Le(y) + rc(y))."""
    return (1.0 - weight) * cache + weight * ratio * (next_emission + next_cache)


def evaluate(tree: Node, rule: Rule, blend: Blend = blend) -> Evaluation:
    """Every path the rule lets through, with its probability and estimate."""
    outcomes: list[Outcome] = []

    def walk(node: Node, probability: float, prefix: float, gathered: float,
             path_variance: float, depth: int) -> None:
        gathered += prefix * node.emission
        state = PathState(node, prefix, path_variance)
        weight = 1.0 if node.is_leaf else rule(state)
        if not 0.0 <= weight <= 1.0:
            raise ValueError(f"continuation weight {weight} at {node.name!r} is not in [0, 1]")
        if node.is_leaf or weight == 0.0:
            outcomes.append(Outcome(probability, gathered + prefix * node.cache,
                                    node.name, depth + 1, path_variance))
            return
        local = state.prefixed_local_variance
        for child, f, p in node.children:
            if weight == 1.0:
                walk(child, probability * p, prefix * f / p, gathered,
                     path_variance + local, depth + 1)
            else:
                estimate = gathered + prefix * blend(node.cache, child.emission, child.cache,
                                                     f / p, weight)
                outcomes.append(Outcome(probability * p, estimate, node.name, depth + 1 + weight,
                                        path_variance + weight ** 2 * local))

    walk(tree, 1.0, 1.0, 0.0, 0.0, 0)
    return Evaluation(tuple(outcomes), tree.value)


def frontiers(tree: Node) -> Iterator[frozenset[str]]:
    """Every set of termination decisions: stop at a node, or continue into all of its
    children and decide there (leaves always stop). A full binary tree of depth d has
    F(d) = 1 + F(d - 1)^2 of them (677 at depth 4)."""
    if tree.is_leaf:
        yield frozenset({tree.name})
        return
    yield frozenset({tree.name})
    for parts in itertools.product(*(list(frontiers(child)) for child, _, _ in tree.children)):
        yield frozenset().union(*parts)


def optimal_frontier(tree: Node, samples: float) -> tuple[frozenset[str], Evaluation]:
    """The decisions with the least MSE at ``samples`` samples, by exhaustive search."""
    best = min(((stops, evaluate(tree, frontier_rule(stops))) for stops in frontiers(tree)),
               key=lambda pair: pair[1].mse(samples))
    return best
