"""The errors a user can cause are known by name: every name is a class that exists,
and the CLI starts without importing the modules that define them."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

from service import errors
from service.errors import USER_ERROR_CLASSES, UsageError, is_user_error
from tests.test_layers import ROOT


def _resolve(name: str) -> type:
    module, _, qualname = name.rpartition(".")
    return getattr(importlib.import_module(module), qualname)


@pytest.mark.parametrize("name", sorted(USER_ERROR_CLASSES))
def test_every_user_error_name_is_an_exception_class(name):
    cls = _resolve(name)
    assert isinstance(cls, type) and issubclass(cls, BaseException)
    assert f"{cls.__module__}.{cls.__qualname__}" == name   # as is_user_error spells it


def test_a_misspelt_or_moved_name_is_caught_by_the_check_above():
    with pytest.raises((ImportError, AttributeError)):
        _resolve("renderers.scenes.SceneErorr")
    with pytest.raises((ImportError, AttributeError)):
        _resolve("renderers.scenes_moved.SceneError")


def test_user_errors_are_recognised_by_their_classes(monkeypatch):
    from renderers.methods import MethodError
    from renderers.scenes import SceneError

    class Narrower(SceneError):
        pass

    assert is_user_error(MethodError("x")) and is_user_error(UsageError("x"))
    assert is_user_error(Narrower("x")) and is_user_error(FileNotFoundError("f"))
    assert not is_user_error(RuntimeError("x")) and not is_user_error(KeyError("k"))
    assert is_user_error(KeyError("k"), "builtins.KeyError")
    monkeypatch.setattr(errors, "USER_ERROR_CLASSES", frozenset())   # planted: none known
    assert not is_user_error(MethodError("x"))


def test_the_cli_starts_without_the_store_the_client_or_the_renderer():
    heavy = ("sqlalchemy", "alembic", "httpx", "mitsuba")
    code = (f"import sys, service.cli; "
            f"print(sorted(m for m in {heavy!r} if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "[]"
