"""``make test-fast``: the listed tests are marked ``fast``, and ``--fast-subset``
fails naming every product module that no test of the run exercised."""

from __future__ import annotations

import pytest

pytest_plugins = ["pytester"]

PRODUCT = {
    "app/__init__.py": "",
    "app/used.py": "def f():\n    return 1\n",
    "app/unused.py": "def g():\n    return 2\n",
    "app/constants.py": "LIMIT = 3\n",     # no function: counts when imported
}
TESTS = """
    import pytest
    from app import unused, used     # imported at collection: does not exercise them

    def test_f():
        assert used.f() == 1

    def test_g():
        assert unused.g() == 2

    @pytest.mark.parametrize("n", [1, 2])
    def test_constants(n):
        from app import constants
        assert constants.LIMIT == 3
    """


@pytest.fixture
def project(pytester):
    pytester.makeini("[pytest]\npythonpath = .\nproduct_packages =\n    app\n"
                     "fast_tests = fast.txt\n")
    pytester.makeconftest('pytest_plugins = ["tests.fast_subset"]\n')
    for path, text in PRODUCT.items():
        pytester.path.joinpath(*path.split("/")).parent.mkdir(exist_ok=True)
        pytester.path.joinpath(*path.split("/")).write_text(text)
    pytester.makepyfile(test_app=TESTS)
    return pytester


def test_a_module_no_listed_test_runs_fails_the_run_by_name(project):
    # test_g is not listed: app.unused is only imported (at collection), never run.
    project.makefile(".txt", fast="test_app.py::test_f  # comment\ntest_app.py::test_constants\n")
    result = project.runpytest_inprocess("--fast-subset")
    result.assert_outcomes(passed=3, deselected=1)
    assert result.ret == pytest.ExitCode.TESTS_FAILED
    result.stdout.fnmatch_lines([
        "fast subset: 3 tests; product modules exercised: 3 of 4 *",
        "FAILED: no test of the fast subset exercised these 1 product modules * app.unused"])

    project.makefile(".txt", fast="test_app.py::test_f\ntest_app.py::test_g\n")
    without_import = project.runpytest_inprocess("--fast-subset")
    assert without_import.ret == pytest.ExitCode.TESTS_FAILED     # constants never imported
    without_import.stdout.fnmatch_lines(["*exercised: 3 of 4 *", "FAILED: * app.constants"])

    project.makefile(".txt", fast="test_app.py::test_f\ntest_app.py::test_g\n"
                                  "test_app.py::test_constants[2]\n")
    every = project.runpytest_inprocess("--fast-subset")
    every.assert_outcomes(passed=3, deselected=1)
    assert every.ret == pytest.ExitCode.OK
    every.stdout.fnmatch_lines(["fast subset: 3 tests; product modules exercised: 4 of 4 *"])
    assert "FAILED" not in every.stdout.str()


def test_a_listed_test_that_does_not_exist_is_an_error(project):
    project.makefile(".txt", fast="test_app.py::test_f\ntest_app.py::test_renamed\n")
    result = project.runpytest_inprocess("--fast-subset")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*fast.txt names tests that were not collected "
                                 "(renamed or removed?): test_app.py::test_renamed*"])


def test_files_without_a_listed_test_are_not_imported(project):
    project.makepyfile(test_other="raise RuntimeError('test_other was imported')\n")
    project.makefile(".txt", fast="test_app.py::test_f\n")
    result = project.runpytest_inprocess("--fast-subset")
    result.assert_outcomes(passed=1, deselected=3)
    assert "test_other was imported" not in result.stdout.str()
    assert project.runpytest_inprocess().ret == pytest.ExitCode.INTERRUPTED    # it is a test file


def test_without_the_option_the_marker_only_selects(project):
    project.makefile(".txt", fast="test_app.py::test_g\ntest_app.py::test_renamed\n")
    result = project.runpytest_inprocess("-m", "fast")
    result.assert_outcomes(passed=1, deselected=3)
    assert "fast subset" not in result.stdout.str()


def test_a_module_run_only_by_a_process_a_test_starts_counts(project):
    """A CLI test runs the product in a child process: its lines count too."""
    project.path.joinpath("app", "child.py").write_text("def h():\n    return 4\n")
    project.makepyfile(test_child="""
        import os
        import subprocess
        import sys

        import pytest

        @pytest.mark.parametrize("call", ["app.child.h()", "None"])
        def test_child(call):
            env = {**os.environ, "PYTHONPATH": os.getcwd()}
            subprocess.run([sys.executable, "-c", f"import app.child; {call}"], env=env,
                           check=True)
        """)
    project.makefile(".txt", fast="test_app.py::test_f\ntest_app.py::test_g\n"
                                  "test_app.py::test_constants\ntest_child.py::test_child[None]\n")
    imported_only = project.runpytest_inprocess("--fast-subset")
    assert imported_only.ret == pytest.ExitCode.TESTS_FAILED
    imported_only.stdout.fnmatch_lines(["*exercised: 4 of 5 *", "FAILED: * app.child"])

    project.makefile(".txt", fast="test_app.py::test_f\ntest_app.py::test_g\n"
                                  "test_app.py::test_constants\ntest_child.py::test_child\n")
    run = project.runpytest_inprocess("--fast-subset")
    assert run.ret == pytest.ExitCode.OK
    run.stdout.fnmatch_lines(["fast subset: 6 tests; product modules exercised: 5 of 5 *"])
