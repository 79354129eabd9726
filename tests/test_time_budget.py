"""``--time-budget`` (make test-fast) keeps the cheapest tests whose recorded times fit."""

from __future__ import annotations

pytest_plugins = ["pytester"]


def test_the_budget_leaves_out_the_slow_test_and_says_so(pytester):
    pytester.makeconftest('pytest_plugins = ["tests.time_budget"]\n')
    pytester.makepyfile(test_three="""
        import time

        def test_quick():
            pass

        def test_slow():
            time.sleep(0.3)

        def test_also_quick():
            pass
        """)
    pytester.runpytest_inprocess().assert_outcomes(passed=3)     # records the times
    result = pytester.runpytest_inprocess("--time-budget", "0.2")
    result.assert_outcomes(passed=2, deselected=1)
    result.stdout.fnmatch_lines(["*time budget: kept tests recorded at 0.0 s; left out 1 "
                                 "tests recorded at 0.3 s*"])
    pytester.makepyfile(test_new="def test_never_timed():\n    pass\n")
    fresh = pytester.runpytest_inprocess("--time-budget", "0.2")
    fresh.assert_outcomes(passed=3, deselected=1)    # an untimed test runs
