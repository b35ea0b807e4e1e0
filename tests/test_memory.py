"""The CLI's fixed glibc mmap threshold (chatterspec.montecarlo)."""

from __future__ import annotations

import platform
import sys

import pytest

from chatterspec.montecarlo import fix_mmap_threshold


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc only"
)
def test_glibc_accepts_the_threshold():
    assert fix_mmap_threshold() is True


def test_elsewhere_it_is_a_quiet_no_op(monkeypatch):
    monkeypatch.setattr(sys, "platform", "darwin")
    assert fix_mmap_threshold() is False
