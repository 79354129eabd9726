"""Declarative description of a neural cache, stored with every run as JSON.

Like a tiny-cuda-nn network config (and the NIRC authors'
``network_config_nirc.json``), a :class:`CacheConfig` is a composition of
input groups — position, direction, normal, roughness, albedo — each with its
encoding, then the MLP, its output, the loss and the optimizer. NRC, NIRC and
the visibility caches are presets of this one config over one implementation
(:class:`renderers.caches.cache.NeuralCache`); nothing else distinguishes them.

Every model is frozen and forbids unknown fields, so a stored config means
exactly one network. Presets take keyword overrides that are deep-merged into
the preset before validation, e.g. ``nirc_config(direction={"sh_bands": 4},
mlp={"hidden_layers": 2})``.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

#: Highest number of SH bands we accept; ``dr.sh_eval`` supports orders 0..9,
#: but beyond 8 bands (64 coefficients) the input layer dominates the MLP cost.
MAX_SH_BANDS = 8
#: Training steps a cache without a weight EMA needs before it counts as trained
#: (:attr:`CacheConfig.min_trained_steps`).
MIN_STEPS_WITHOUT_EMA = 32


class _Frozen(BaseModel):
    """Base of every config model: immutable, unknown fields are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class HashGridConfig(_Frozen):
    """Multiresolution hash encoding of the scene-normalised position [MESK22].

    ``log2_hashmap_size`` bounds the vertices per level; coarse levels that fit
    are stored densely (Dr.Jit's ``HashGridEncoding``). Level l has
    ``base_resolution * per_level_scale**l`` cells per axis. The scene bounding
    box is grown by ``bbox_margin`` (fraction of its extent per side) before it
    is mapped to [0, 1]^3, so that surface points on the box stay inside.
    """

    n_levels: int = Field(12, ge=1, le=32)
    n_features_per_level: Literal[1, 2, 4, 8] = 2
    log2_hashmap_size: int = Field(16, ge=8, le=24)
    base_resolution: int = Field(16, ge=2, le=4096)
    per_level_scale: float = Field(1.5, gt=1.0, le=4.0)
    bbox_margin: float = Field(0.01, ge=0.0, le=1.0)
    init_scale: float = Field(1e-4, gt=0.0)

    @property
    def n_features(self) -> int:
        return self.n_levels * self.n_features_per_level

    @property
    def finest_resolution(self) -> float:
        return self.base_resolution * self.per_level_scale ** (self.n_levels - 1)


class ScreenLatentConfig(_Frozen):
    """Screen-space latent features (SS NIRC, NIRC paper Sec. 6.1): one trainable vector
    of ``features`` floats per film pixel, read at the pixel the shading point projects
    to, in place of the hash grid (74 floats: the paper's equal-memory preset beside 5
    SH bands and 11 vMF lobes). Initialised uniformly in [-init_scale, init_scale] like
    the hash grid's table; trained by the same Adam as the MLP."""

    features: int = Field(74, ge=1, le=1024)
    init_scale: float = Field(1e-4, gt=0.0)


class DirectionEncodingConfig(_Frozen):
    """Encoding of the query direction (w_i for NIRC, w_o for NRC).

    ``sh``: real spherical harmonics with ``sh_bands`` bands, i.e.
    ``sh_bands**2`` coefficients (``dr.sh_eval(d, sh_bands - 1)``) [VHM*22].
    ``oneblob``: the spherical coordinates (theta/pi, phi/2pi), each one-blob
    encoded with ``bins`` bins [MRNK21]. ``none``: no direction input (e.g. a
    per-light visibility cache whose outputs are the lights).
    """

    kind: Literal["sh", "oneblob", "none"] = "sh"
    sh_bands: int = 5
    bins: int = 4

    @model_validator(mode="after")
    def _check(self) -> DirectionEncodingConfig:
        if self.kind == "sh" and not 1 <= self.sh_bands <= MAX_SH_BANDS:
            raise ValueError(
                f"direction.sh_bands must be between 1 and {MAX_SH_BANDS} (B bands give "
                f"B^2 coefficients), got {self.sh_bands}"
            )
        if self.kind == "oneblob" and not 1 <= self.bins <= 64:
            raise ValueError(f"direction.bins must be between 1 and 64, got {self.bins}")
        return self

    @property
    def n_features(self) -> int:
        if self.kind == "sh":
            return self.sh_bands**2
        if self.kind == "oneblob":
            return 2 * self.bins
        return 0


class ScalarEncodingConfig(_Frozen):
    """Encoding of a surface input: ``oneblob`` with ``bins`` bins per
    component [Müller et al. 2019], or ``identity`` (the raw values)."""

    kind: Literal["oneblob", "identity"] = "oneblob"
    bins: int = Field(4, ge=1, le=64)

    def n_features(self, components: int) -> int:
        return components * (self.bins if self.kind == "oneblob" else 1)


class MLPConfig(_Frozen):
    """Fully connected network: ``hidden_layers`` layers of ``width`` neurons."""

    width: int = Field(64, ge=1, le=1024)
    hidden_layers: int = Field(4, ge=1, le=16)
    activation: Literal["relu", "leaky_relu"] = "relu"
    leaky_slope: float = Field(0.01, ge=0.0, lt=1.0)


class OutputConfig(_Frozen):
    """Network outputs and how they are activated.

    ``clamped_linear``: linear while training (so that the relative loss sees
    negative predictions and pushes them up), clamped at >= 0 when used for
    rendering. ``sigmoid``: in [0, 1] in both (visibility caches, NVC Sec. 5).
    """

    n_outputs: int = Field(3, ge=1, le=64)
    activation: Literal["clamped_linear", "sigmoid"] = "clamped_linear"


class LossConfig(_Frozen):
    """Training loss.

    ``relative_l2`` is Eq. 18 of the NIRC paper (after [LMH*18], as used by
    NRC): (pred - target)^2 / (sg(pred)^2 + epsilon), with p_r folded into the
    training distribution. ``relative_to='luminance'`` normalises every
    channel by the luminance of the prediction (tiny-cuda-nn's
    RelativeL2Luminance, the authors' code); ``'channel'`` by each channel's
    own prediction. ``l2`` is the plain squared error, Eq. 17 (visibility
    caches). ``variance`` is L_V, Eq. 16: the squared residual minus the
    residual's expectation F_r at the record's shading point, which is
    estimated from ``group_size`` records sharing that point (consecutive
    records form a group; renderers/caches/losses.py).
    """

    kind: Literal["relative_l2", "l2", "variance"] = "relative_l2"
    relative_to: Literal["luminance", "channel"] = "luminance"
    epsilon: float = Field(0.01, gt=0.0)
    group_size: int = Field(8, ge=2, le=256)

    @property
    def records_per_point(self) -> int:
        """Consecutive training records that share one shading point: ``group_size``
        for L_V (its F_r estimate), else 1."""
        return self.group_size if self.kind == "variance" else 1


class OptimizerConfig(_Frozen):
    """Adam [Kingma & Ba] over the hash-grid parameters and the MLP weights.

    ``lr_end``/``lr_decay_steps``: optional linear decay of the learning rate
    from ``lr`` to ``lr_end`` over the first ``lr_decay_steps`` steps (the
    per-light visibility cache decays 0.05 -> 0.001 over 200 steps).
    """

    lr: float = Field(1e-2, gt=0.0)
    beta1: float = Field(0.9, ge=0.0, lt=1.0)
    beta2: float = Field(0.99, ge=0.0, lt=1.0)
    eps: float = Field(1e-8, gt=0.0)
    lr_end: float | None = Field(None, gt=0.0)
    lr_decay_steps: int = Field(0, ge=0)

    def learning_rate_at(self, step: Any) -> Any:
        """Learning rate of the 0-based optimizer step ``step`` (a Dr.Jit UInt32 on the
        device: a frozen training step reads it there, renderers.frozen): ``lr``, or
        linear from ``lr`` to ``lr_end`` over ``lr_decay_steps`` steps, then ``lr_end``."""
        if self.lr_end is None or self.lr_decay_steps == 0:
            return self.lr
        import drjit as dr

        # In double precision, rounded once to single: the value a host-side schedule
        # (Python floats) would hand to Adam, bit for bit.
        t = dr.minimum(dr.float64_array_t(type(step))(step) / self.lr_decay_steps, 1.0)
        return dr.float32_array_t(type(step))(self.lr + (self.lr_end - self.lr) * t)


class ConvergedTrainingConfig(_Frozen):
    """Optional rule: fewer optimizer steps per frame once the loss has converged.

    After every frame that trained, the mean loss of its steps m_f enters an
    exponential moving average over frames, E_f = d E_{f-1} + (1 - d) m_f
    (E_0 = m_0, d = ``ema_decay``). A frame is *converged* when at least
    ``window`` + 1 frames have trained and |E_f - E_{f-window}| <
    ``tolerance`` x E_{f-window}: the smoothed loss moved by less than
    ``tolerance`` (relative) over the last ``window`` frames. The next frame
    then takes min(steps, ``steps``) steps instead of its budget. ``steps`` >=
    1, so the loss keeps being measured: when it moves again (a dynamic
    scene, a light switched on) the full budget resumes at the next frame.

    Off by default (``CacheConfig.converged_training = None``): the papers
    train every frame's full budget, and results stay comparable with it.
    """

    window: int = Field(8, ge=1, le=10_000)
    tolerance: float = Field(0.02, gt=0.0, lt=1.0)
    ema_decay: float = Field(0.8, ge=0.0, lt=1.0)
    steps: int = Field(1, ge=1, le=1024)


class CacheConfig(_Frozen):
    """One neural cache: input encodings, MLP, output, loss, optimizer, schedule.

    Inputs are concatenated in this order: hash-grid(position), normal,
    roughness, albedo, specular albedo (the per-surface features, computed once
    per shading point, NIRC Sec. 4.5), then the direction encoding.
    ``screen_latent``, when set, replaces the hash grid by per-pixel latent features
    (:class:`ScreenLatentConfig`; ``position`` is then unused).
    ``normal``/``roughness`` = None leave the input out; ``albedo`` and
    ``albedo_spec`` are identity-encoded RGB when enabled. Roughness r enters
    as 1 - exp(-r) [MRNK21] so that it lies in [0, 1).

    ``ema_decay``: when set, inference uses an exponential moving average of
    the weights (debiased like Adam's moments), which cuts the noise of online
    training; None uses the latest weights.

    ``converged_training``: optional rule that takes fewer steps per frame
    once the loss has converged (:class:`ConvergedTrainingConfig`); None
    (default) always trains the full budget.
    """

    position: HashGridConfig = HashGridConfig()
    screen_latent: ScreenLatentConfig | None = None
    direction: DirectionEncodingConfig = DirectionEncodingConfig()
    normal: ScalarEncodingConfig | None = ScalarEncodingConfig()
    roughness: ScalarEncodingConfig | None = ScalarEncodingConfig()
    albedo: bool = True
    albedo_spec: bool = False
    mlp: MLPConfig = MLPConfig()
    output: OutputConfig = OutputConfig()
    loss: LossConfig = LossConfig()
    optimizer: OptimizerConfig = OptimizerConfig()
    ema_decay: float | None = 0.99
    batch_size: int = Field(16384, ge=1, le=1 << 22)
    steps_per_frame: int = Field(4, ge=0, le=1024)
    converged_training: ConvergedTrainingConfig | None = None

    @model_validator(mode="after")
    def _check(self) -> CacheConfig:
        if self.ema_decay is not None and not 0.0 < self.ema_decay < 1.0:
            raise ValueError(
                f"ema_decay must be in (0, 1) (e.g. 0.99) or None, got {self.ema_decay}"
            )
        if (self.loss.kind == "relative_l2" and self.loss.relative_to == "luminance"
                and self.output.n_outputs != 3):
            raise ValueError(
                "loss.relative_to='luminance' needs RGB outputs (output.n_outputs=3); "
                f"got n_outputs={self.output.n_outputs}: use relative_to='channel' or loss 'l2'"
            )
        return self

    # ---- Derived sizes ----
    @property
    def n_surface_features(self) -> int:
        """Width of the direction-independent part of the network input."""
        n = (self.position.n_features if self.screen_latent is None
             else self.screen_latent.features)
        if self.normal is not None:
            n += self.normal.n_features(3)
        if self.roughness is not None:
            n += self.roughness.n_features(1)
        n += 3 * int(self.albedo) + 3 * int(self.albedo_spec)
        return n

    @property
    def n_inputs(self) -> int:
        return self.n_surface_features + self.direction.n_features

    @property
    def min_trained_steps(self) -> int:
        """Successful optimizer steps below which a run's cache counts as barely trained
        (the quality verdict ``undertrained-cache``, docs/results.md).

        With a weight EMA of decay d the cache infers with an average over about the
        last 1 / (1 - d) steps (100 for the radiance caches' 0.99): before that many
        steps it is an average dominated by the first, barely trained weights. Without
        an EMA (the visibility caches) 32 steps: the NVC paper's Fig. 6 shows the error
        "significantly reduced after 20 to 30 training steps" (Sec. 4.1, Fig. 6).
        """
        if self.ema_decay is not None:
            return math.ceil(1.0 / (1.0 - self.ema_decay))
        return MIN_STEPS_WITHOUT_EMA

    def to_json(self) -> str:
        """Canonical JSON (what is stored with a run); inverse of :meth:`from_json`."""
        return self.model_dump_json()

    @classmethod
    def from_json(cls, text: str) -> CacheConfig:
        return cls.model_validate_json(text)


# --------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------

def _deep_merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``overrides`` applied; nested dicts merge, other values replace."""
    merged = dict(base)
    for key, value in overrides.items():
        if isinstance(value, BaseModel):
            value = value.model_dump()
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


#: Named network sizes, applied by every preset function through the
#: ``preset`` keyword (``nirc_config(preset="small")``, or ``cache={"preset":
#: "small"}`` in a method's parameters) before the other overrides.
#: ``small``: the visibility-cache paper's 2 x 32 MLP (same inputs, grid and
#: training); ~6x fewer MLP FLOPs per query than 64 x 4, at some accuracy
#: (docs/training.md, "Speed of the neural work").
NETWORK_PRESETS: dict[str, dict[str, Any]] = {
    "small": {"mlp": {"width": 32, "hidden_layers": 2}},
}


def _preset(base: dict[str, Any], overrides: dict[str, Any]) -> CacheConfig:
    overrides = dict(overrides)
    preset = overrides.pop("preset", None)
    if preset is not None:
        if preset not in NETWORK_PRESETS:
            raise ValueError(f"unknown cache preset {preset!r}; choose one of "
                             f"{sorted(NETWORK_PRESETS)}")
        base = _deep_merge(base, NETWORK_PRESETS[preset])
    unknown = set(overrides) - set(CacheConfig.model_fields)
    if unknown:
        raise ValueError(
            f"unknown cache config field(s) {sorted(unknown)}; "
            f"valid fields are {sorted(CacheConfig.model_fields)} and 'preset'"
        )
    return CacheConfig.model_validate(_deep_merge(base, overrides))


def nirc_config(**overrides: Any) -> CacheConfig:
    """Neural Incident Radiance Cache: L_ind(x, w_i) (NIRC paper Sec. 4, Eq. 9).

    ====================  ===================  ===================  ===================
    setting               paper (4.4, 6.2)     authors' code        default here
    ====================  ===================  ===================  ===================
    position hash grid    12 lv x 2 features   12 x 2, table 2^19   12 x 2, table 2^16,
                                                                    per-level scale 1.5
    direction w_i         SH, 4 bands          SH, 5 bands          SH, 5 bands
    normal                as NRC [MRNK21] (*)  OneBlob(4)           OneBlob(4)
    roughness 1-exp(-r)   as NRC (*)           OneBlob(4)           OneBlob(4)
    albedo                as NRC (*)           identity             identity
    MLP                   64 x 4, ReLU         64 x 4, ReLU         64 x 4, ReLU
    loss                  Eq. 18               rel. L2 luminance    rel. L2 luminance
    Adam                  lr 1e-2              lr 1e-3, b 0.9/0.99  lr 1e-2, b 0.9/0.99
    weight EMA            not mentioned        yes                  0.99
    steps per frame       4                    2                    4
    ====================  ===================  ===================  ===================

    (*) "without altering their corresponding encodings" (Sec. 4.4).

    The defaults are what measured best in our CPU prototype (docs/design.md,
    "Neural caches on this CPU"): 5 SH bands, lr 1e-2 with an EMA of 0.99 (the
    EMA cut the bias ~3x), per-level scale 1.5 (scale 2 with 12 levels reaches
    resolution 32768, far finer than small scenes need). The table is 2^16
    because 2^19 x 12 levels is 10M parameters and ~10 ms per Adam step here;
    raise ``position.log2_hashmap_size`` for large scenes.
    """
    base = CacheConfig(
        position=HashGridConfig(n_levels=12, n_features_per_level=2, log2_hashmap_size=16,
                                base_resolution=16, per_level_scale=1.5),
        direction=DirectionEncodingConfig(kind="sh", sh_bands=5),
        normal=ScalarEncodingConfig(kind="oneblob", bins=4),
        roughness=ScalarEncodingConfig(kind="oneblob", bins=4),
        albedo=True,
        albedo_spec=False,
        mlp=MLPConfig(width=64, hidden_layers=4, activation="relu"),
        output=OutputConfig(n_outputs=3, activation="clamped_linear"),
        loss=LossConfig(kind="relative_l2", relative_to="luminance", epsilon=0.01),
        optimizer=OptimizerConfig(lr=1e-2, beta1=0.9, beta2=0.99, eps=1e-8),
        ema_decay=0.99,
        batch_size=16384,
        steps_per_frame=4,
    )
    return _preset(base.model_dump(), overrides)


def ss_nirc_config(**overrides: Any) -> CacheConfig:
    """Screen-space NIRC (NIRC paper Sec. 6.1): :func:`nirc_config` with one latent
    vector of 74 floats per pixel instead of the hash grid and 6 hidden layers ("both
    NIRC models ... 6 layers"); the other inputs, the loss and the training as NIRC's."""
    base = nirc_config(screen_latent=ScreenLatentConfig(), mlp={"hidden_layers": 6})
    return _preset(base.model_dump(), overrides)


def nrc_config(**overrides: Any) -> CacheConfig:
    """Neural Radiance Cache [MRNK21]: outgoing radiance L_o(x, w_o).

    Inputs as docs/design.md lists them: hash-grid(position) (same grid as
    :func:`nirc_config`; the original NRC used a frequency encoding, its
    tiny-cuda-nn successor the hash grid), w_o one-blob encoded on spherical
    coordinates (4 bins), normal OneBlob(4) per component, roughness
    1 - exp(-r) OneBlob(4), diffuse and specular albedo (identity; the method
    demodulates the output by their sum). MLP 64 wide x 5 hidden layers, ReLU
    (the 7-layer network of MRNK21), relative L2 on luminance, Adam lr 1e-2
    (beta 0.9/0.99), EMA 0.99 of the weights, 4 steps of 16384 per frame.
    """
    base = nirc_config(
        direction={"kind": "oneblob", "bins": 4},
        albedo_spec=True,
        mlp={"hidden_layers": 5},
    )
    return _preset(base.model_dump(), overrides)


def visibility_config(n_outputs: int, **overrides: Any) -> CacheConfig:
    """Neural Visibility Cache (visibility paper Sec. 3; NIRC paper Sec. 5).

    Per-light visibility V(x) in [0, 1] for ``n_outputs`` (<= 32) lights:
    hash grid 10 levels, base resolution 16, 4 features per level, table 2^14
    (~0.56M parameters, the paper's count); MLP 2 x 32,
    leaky ReLU 0.01; sigmoid outputs; L2 loss; Adam lr 0.05 decaying linearly
    to 0.001 over 200 steps; 1 step per frame on 4096 + 4096 points. No
    direction or surface inputs by default; the environment-map NVC adds a
    direction with ``direction={"kind": "sh", "sh_bands": 4}`` and 1 output.
    """
    base = CacheConfig(
        position=HashGridConfig(n_levels=10, n_features_per_level=4, log2_hashmap_size=14,
                                base_resolution=16, per_level_scale=1.5),
        direction=DirectionEncodingConfig(kind="none"),
        normal=None,
        roughness=None,
        albedo=False,
        albedo_spec=False,
        mlp=MLPConfig(width=32, hidden_layers=2, activation="leaky_relu", leaky_slope=0.01),
        output=OutputConfig(n_outputs=n_outputs, activation="sigmoid"),
        loss=LossConfig(kind="l2", relative_to="channel"),
        optimizer=OptimizerConfig(lr=0.05, beta1=0.9, beta2=0.99, eps=1e-8,
                                  lr_end=1e-3, lr_decay_steps=200),
        ema_decay=None,
        batch_size=8192,
        steps_per_frame=1,
    )
    return _preset(base.model_dump(), overrides)



def direct_light_config(**overrides: Any) -> CacheConfig:
    """NRC DI, the visibility paper's radiance-cache baseline (Sec. 4.2): the direct
    light reflected at a position, RGB.

    The network and training of :func:`visibility_config` ("exactly the same
    network architecture ... and training data procedure") with three unbounded
    outputs: linear while training and clamped at >= 0 when rendering
    (``clamped_linear``; the paper's leaky ReLU output differs from it only below
    0, where direct light never is), and NRC's relative L2 loss on luminance
    [MRNK21] instead of L2, since radiance, unlike visibility, spans orders of
    magnitude.
    """
    base = visibility_config(3, output={"activation": "clamped_linear"},
                             loss={"kind": "relative_l2", "relative_to": "luminance"})
    return _preset(base.model_dump(), overrides)
