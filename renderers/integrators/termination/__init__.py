"""Path termination as one object the path-tracing core asks at each vertex.

As light selection is one object (``renderers.integrators.lights``, after
pbrt-v4's ``LightSampler``), the decision where a path hands over to a
radiance cache is one object, a :class:`TerminationPolicy`, which the caching
integrators (``nirc``, ``nrc``) ask at every vertex. A policy answers with a
*continuation weight* alpha in [0, 1] per lane: 1 continues the path, 0 ends it
into the cache, and a value in between blends the cache (weight 1 - alpha) with
one more segment (weight alpha; the next segment includes the direct light at
the next vertex). What a policy may read is a :class:`TerminationQuery`:

* the vertex (``renderers.integrators.path.Vertex``: position, BSDF, the
  continuation sample and its pdf, throughput, depth);
* the lanes at which the cache may replace the next segment (``usable``);
* the per-path state carried along the path (``state``: the spread of the path
  for the spread heuristic, the pixel's v1 mask of adaptive termination, and
  ``termination_value``, one number a policy keeps for itself, e.g. an
  accumulated variance; the grid's integrator also carries the state a policy
  declares, :meth:`TerminationPolicy.path_state`);
* the N_c coupling of NIRC (``nc``: the number of cache samples at the first
  vertex and at later ones; the Balanced Termination Heuristic depends on it);
* read access to the cache's statistics at the current vertex
  (:meth:`TerminationQuery.statistics`; caches that keep no statistics raise). A
  decision reads the path's prefix only, never its continuation sample: a rule whose
  decision to stop depends on the sample that would continue the path biases the
  image ([VTT24] Sec. 3).

Each policy is declared in its own module of this package with its own typed
parameters (a pydantic model, ``Params``), the caches it serves (``serves``:
'incident' for NIRC's cache of incident radiance, 'outgoing' for NRC's cache
of outgoing radiance, 'grid' for the hashed grid with three moments of the
`grid-cache` method, whose records hold the full reflected radiance and the
statistics the variance-trading policies read) and what it needs of N_c. Each registers itself with
``@register``, and importing this package imports every module in it
(renderers/registry.py), so adding a policy adds one file; the
methods' parameter models list the policies of the kind they serve and hold the
chosen one's parameters as its tagged model (:func:`params_model`, members of
:func:`termination_params_type`), validated once where the method's parameters are
parsed; :func:`make_policy` takes that object as it is. Reading the
registry does not import Mitsuba: policies import it where they evaluate.
docs/termination.md says how to add one.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidatorFunctionWrapHandler,
    create_model,
    field_serializer,
    field_validator,
)

from renderers.registry import Registry, discover

if TYPE_CHECKING:
    from renderers.integrators.cached import CacheState
    from renderers.integrators.path import Vertex

CacheKind = Literal["incident", "outgoing", "grid"]


class NoParams(BaseModel):
    """The parameters of a policy that has none of its own."""

    model_config = ConfigDict(extra="forbid", frozen=True)


@dataclass(frozen=True)
class TerminationSettings:
    """What a policy takes from the method besides its own parameters: c of the
    spread heuristic (``sph_c``, shared with the training paths) and N_c at the
    first vertex and at later ones (NIRC; (0, 0) for a cache without sampled queries)."""

    sph_c: float
    nc: tuple[int, int] = (0, 0)


@dataclass
class TerminationQuery:
    """What a policy sees at one vertex (all arrays per lane; module doc)."""

    vertex: Vertex
    state: CacheState
    usable: Any                   # mi.Bool: the cache may replace the next segment here
    cache: Any = None             # the integrator's cache (statistics, where it keeps any)

    def statistics(self) -> Any:
        """The cache's statistics at this vertex."""
        reader = getattr(self.cache, "statistics", None)
        if reader is None:
            raise TypeError(f"{type(self.cache).__name__} keeps no statistics")
        return reader(self.vertex.si, self.usable)


class TerminationPolicy:
    """Base of the termination policies (module doc).

    A subclass sets ``name``, ``description``, ``serves`` and, where it differs
    from the defaults, ``Params``, ``nc_entries`` (how many N_c values it takes:
    1, or 2 for N_c at the first vertex and later) and ``default_nc``; it
    implements :meth:`continuation` and, where it keeps more along a path than
    ``termination_value``, :meth:`path_state`. ``blends``: whether its weights can
    lie strictly between 0 and 1 (NIRC blends its cache term with the continuation;
    NRC, whose cache ends the path, refuses such a policy).
    """

    name: ClassVar[str]
    description: ClassVar[str]
    serves: ClassVar[frozenset[str]]
    Params: ClassVar[type[BaseModel]] = NoParams
    nc_entries: ClassVar[int] = 1
    default_nc: ClassVar[tuple[int, ...]] = (4,)
    blends: ClassVar[bool] = False

    def __init__(self, params: BaseModel, settings: TerminationSettings) -> None:
        self.params = params
        self.settings = settings

    def continuation(self, query: TerminationQuery) -> tuple[Any, CacheState]:
        """(alpha per lane, the path state): the continuation weight in [0, 1]."""
        raise NotImplementedError

    def path_state(self) -> dict[str, Any]:
        """The per-path values this policy keeps besides ``termination_value``, by
        name, as they start at the camera (Dr.Jit arrays). The integrator carries
        them through its loop as ``state.policy_state`` without reading them; the
        policy reads and updates them in :meth:`continuation`. Only the grid's
        integrator carries them (renderers/integrators/grid_cache.py)."""
        return {}


#: The policies by name; a policy's module registers it with ``@register``.
POLICIES: Registry[type[TerminationPolicy]] = Registry("termination policies",
                                                       lambda cls: cls.name)
register = POLICIES.register


def policy_names(kind: CacheKind) -> tuple[str, ...]:
    """The registered policies that serve a cache of ``kind``, in registration order."""
    return tuple(name for name, cls in POLICIES.items() if kind in cls.serves)


def get_policy(name: str) -> type[TerminationPolicy]:
    try:
        return POLICIES[name]
    except KeyError:
        raise ValueError(f"unknown termination policy {name!r}; "
                         f"known: {', '.join(POLICIES)}") from None


def _whole_number_as_given(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    """A float parameter given a whole number keeps it (checked as the float it equals),
    so that it dumps as given: parameters stored before the policies' models were typed
    hold it so, and their keys hash it so."""
    checked = handler(value)
    return value if type(value) is int and checked == value else checked


def _as_held(value: Any) -> Any:
    return value


@functools.cache
def params_model(cls: type[TerminationPolicy]) -> type[BaseModel]:
    """``cls.Params`` tagged with the policy's name: its field ``policy`` (a name no
    policy may give a parameter of its own) holds ``cls.name``, so one object says which
    policy it configures and how. The methods' parameter models hold one of these.
    A whole number given for a float parameter is kept (:func:`_whole_number_as_given`)."""
    floats = [name for name, field in cls.Params.model_fields.items() if field.annotation is float]
    validators = ({"_whole_numbers_as_given": field_validator(*floats, mode="wrap")(
                       _whole_number_as_given),
                   "_dumped_as_held": field_serializer(*floats)(_as_held)} if floats else {})
    return create_model(f"{cls.__name__}Params", __base__=cls.Params,
                        __module__=cls.__module__, __validators__=validators,
                        policy=(Literal[cls.name], cls.name))


def policy_params(name: str, **values: Any) -> BaseModel:
    """The parameters of the policy ``name``, ``values`` validated by its model (the
    defaults where none is given)."""
    return params_model(get_policy(name))(**values)


def termination_params_type(kind: CacheKind) -> Any:
    """The type of a method's ``termination``: the union of the tagged parameter models
    (:func:`params_model`) of the policies registered now that serve a cache of
    ``kind``, told apart by their ``policy`` name."""
    members = tuple(params_model(POLICIES[name]) for name in policy_names(kind))
    if len(members) == 1:
        return members[0]
    return Annotated[Union[members], Field(discriminator="policy")]  # noqa: UP007


def make_policy(params: BaseModel, settings: TerminationSettings) -> TerminationPolicy:
    """The policy that the validated ``params`` (a :func:`params_model` instance) name,
    configured by them; nothing is validated here."""
    return get_policy(params.policy)(params, settings)  # type: ignore[attr-defined]


discover(__name__, __path__)
