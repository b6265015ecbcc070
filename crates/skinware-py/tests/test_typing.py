"""The package ships type stubs that match the native module, and a
`py.typed` marker."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import skinware


def test_the_package_is_marked_typed():
    package = Path(skinware.__file__).parent
    assert (package / "py.typed").exists()
    assert (package / "_skinware.pyi").exists()


def test_stubs_match_the_native_module():
    try:
        import mypy  # noqa: F401
    except ImportError:
        if os.environ.get("CI"):
            pytest.fail("mypy is needed to check the stubs: pip install mypy")
        pytest.skip("mypy is not installed: the stubs are not checked against the module")
    result = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "--ignore-disjoint-bases", "skinware"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr
