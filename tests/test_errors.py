"""Every error the library defines derives from :class:`feeder.errors.FeederError`: a caller can
catch the library's errors with one class (and the expected ones by theirs)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from pathlib import Path

import pytest

import feeder
from feeder.cli import main
from feeder.errors import SHOWN_CHARS, FeederError, shown


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


def test_a_long_missing_file_is_named_by_its_end_and_a_blob_is_clipped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A path longer than a line's quote keeps its file name (its start and end around "…"); a
    pasted blob is clipped to :data:`SHOWN_CHARS`."""
    deep = tmp_path / ("d" * 100) / "e" / "missing_scan.spm"
    with pytest.raises(SystemExit) as exit_:
        main(["contact", "--part", "300x300x50", "--surface", str(deep)])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1
    assert len(str(deep)) > SHOWN_CHARS and f"no such file: '{str(deep)[:40]}" in err
    assert "…" in err and err.endswith("/e/missing_scan.spm'")
    blob = shown("x" * 10_000)
    assert blob == repr("x" * 79 + "…" + "x" * 80) and len(blob) == SHOWN_CHARS + 2
    assert shown("/short/path.toml") == "'/short/path.toml'"
