"""Every error the library defines derives from :class:`feeder.errors.FeederError`: a caller can
catch the library's errors with one class (and the expected ones by theirs)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import feeder
from feeder.errors import FeederError


def _library_exceptions() -> list[type[BaseException]]:
    found = []
    for info in pkgutil.walk_packages(feeder.__path__, "feeder."):
        if info.name.endswith(".__main__"):  # runs the command line when imported
            continue
        try:
            module = importlib.import_module(info.name)
        except ImportError:  # an optional extra that is not installed
            continue
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if issubclass(cls, BaseException) and cls.__module__ == info.name:
                found.append(cls)
    return found


def test_every_library_error_is_a_feeder_error() -> None:
    found = _library_exceptions()
    assert len(found) >= 10  # the walk did find the library's errors
    strays = [f"{cls.__module__}.{cls.__name__}" for cls in found if not issubclass(cls, FeederError)]
    assert strays == []
