"""``nirc-bench ci --baseline-ref``: the latest stored results of a commit or branch
(SQLite and PostgreSQL)."""

from __future__ import annotations

from jobs.ci.ci import stored_baseline
from jobs.ci.ci_suite import CI_METRICS, Suite
from tests.jobs.ci_fakes import fake_run
from tests.jobs.factories import run_fields


def test_the_latest_commit_of_a_branch_is_the_baseline(store):
    entry = Suite.model_validate({"scenes": ["cornell-box"], "resolution": 16, "frames": 4,
                                  "methods": [{"method": "pt"}]}).entries()[0]
    config = {"params": entry.params, "width": 16, "height": 16, "spp": 1, "frames": 4}

    def add(commit: str, branch: str | None, seeds: dict[int, float], **fields) -> int:
        run = store.add_run(run_fields(**{**config, "git_commit": commit, "git_branch": branch,
                                          **fields}),
                            [{"seed": s, "metrics": {"mrse": v}, "timings": {}}
                             for s, v in seeds.items()])
        return run.id

    add("aaa111", "main", {0: 1.0, 1: 1.0})                    # an older commit of main
    add("bbb222", "main", {0: 2.0, 1: 2.0})                    # the latest: two runs,
    add("bbb222", "main", {2: 3.0, 3: 3.0})                    # seeds added in groups
    add("ccc333", "feature", {0: 9.0, 1: 9.0})                 # another branch
    add("ddd444", "main", {0: 8.0, 1: 8.0}, frames=8)          # another configuration
    add("eee555", "main", {0: 7.0, 1: 7.0}, status="failed")
    first = add("fff666", "main", {0: 5.0, 1: 5.0})            # this invocation's own run
    mrse = CI_METRICS["mrse"]

    row = stored_baseline(store, "main")(entry, fake_run(first, "pt", {}), mrse)
    assert row.commit == "bbb222" and row.branch == "main"
    assert row.seeds == [0, 1, 2, 3] and row.values == [2.0, 2.0, 3.0, 3.0]
    by_commit = stored_baseline(store, "aaa1")(entry, fake_run(first, "pt", {}), mrse)
    assert by_commit.commit == "aaa111" and by_commit.values == [1.0, 1.0]
    assert stored_baseline(store, "nothing")(entry, fake_run(first, "pt", {}), mrse) is None
