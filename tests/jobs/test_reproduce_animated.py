"""The shared reading of animated runs (jobs.reproduce.animated): a figure's stored run
is found again under its own spec only, and each point is counted as reused or
rendered. Planted: a key that does not depend on the spec (every spec of the figure
finds the first one's run), rejected."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from jobs.reproduce import animated


class FakeStore:
    """Runs stored by id and idempotency key, as the executor would store them."""

    def __init__(self) -> None:
        self.runs: dict[int, Any] = {}
        self.keys: dict[str, Any] = {}

    def find_run_by_idempotency_key(self, key: str) -> Any:
        return self.keys.get(key)

    def get_run(self, run_id: int) -> Any:
        return self.runs[run_id]


@pytest.mark.parametrize("planted", [False, True])
def test_a_figures_run_is_found_by_its_spec(monkeypatch: pytest.MonkeyPatch, planted: bool
                                            ) -> None:
    from jobs.protocol import executor
    from jobs.protocol.spec import ReferenceSpec, RenderSpec
    from renderers import seeding
    from renderers.scenes.animation import Animation

    store, asked = FakeStore(), []

    def execute(job: Any, store: FakeStore, settings: Any, progress: Any = None,
                idempotency_key: str | None = None, reuse: bool = False) -> Any:
        asked.append(reuse)
        run = SimpleNamespace(id=len(store.runs), method=job.spec.method)
        store.runs[run.id] = run
        if idempotency_key is not None:
            store.keys[idempotency_key] = run
        return SimpleNamespace(run_id=run.id, reused=reuse)

    monkeypatch.setattr(executor, "execute", execute)
    if planted:
        monkeypatch.setattr(seeding, "digest", lambda *parts, length=32: "one key")
    ctx = SimpleNamespace(store=store, settings=None, progress=None, work={})

    def spec(method: str) -> RenderSpec:
        return RenderSpec(scene="cornell-box", method=method, resolution=8, frames=2,
                          reference=ReferenceSpec(spp=16),
                          animation=Animation(disocclusions=[1]))

    methods = ["pt", "nrc", "pt"]
    runs = [animated.stored_run(ctx, spec(method), figure="test-fig") for method in methods]
    found = ([run.method for run in runs] == methods
             and ctx.work == {"points_rendered": 2, "points_reused": 1})
    assert found != planted, (ctx.work, [run.method for run in runs])
    # Without a figure the executor finds a run of the same spec and commit itself.
    animated.stored_run(ctx, spec("pt"))
    assert asked[-1] is True and asked[:-1] == [False] * len(asked[:-1])
