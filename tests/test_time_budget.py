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


def test_untimed_tests_stop_when_the_budget_is_spent(pytester):
    """A fresh checkout records nothing: the run stops starting tests once the budget has
    passed, whatever their number."""
    pytester.makeconftest('pytest_plugins = ["tests.time_budget"]\n')
    pytester.makepyfile(test_many="""
        import time
        import pytest

        @pytest.mark.parametrize("n", range(20))
        def test_takes_a_while(n):
            time.sleep(0.05)
        """)
    first = pytester.runpytest_inprocess("--time-budget", "0.2", "-v")
    outcomes = first.parseoutcomes()
    assert 3 <= outcomes["passed"] <= 6 and first.ret == 0 and "skipped" not in outcomes
    first.stdout.fnmatch_lines([f"*time budget: spent after {outcomes['passed']} tests; the "
                                f"other {20 - outcomes['passed']} were not started*"])
    # The next run starts with the tests still untimed: the record grows run by run.
    second = pytester.runpytest_inprocess("--time-budget", "0.2", "-v")
    ran_first = {line.split(" ")[0] for line in first.stdout.lines if " PASSED" in line}
    ran_second = {line.split(" ")[0] for line in second.stdout.lines if " PASSED" in line}
    assert ran_second and not ran_second & ran_first
