"""The one revision helper: what checkpoints, the level server, reports and benchmarks record."""

from __future__ import annotations

import subprocess

import pytest

from cec import checkpoints


def test_it_names_this_checkout_and_flags_changes() -> None:
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout
    full, short = checkpoints.code_version(), checkpoints.code_version(short=True)
    assert full.removesuffix("+dirty") == head.strip()
    assert head.startswith(short.removesuffix("+dirty")) and len(short.removesuffix("+dirty")) < 40
    assert full.endswith("+dirty") == short.endswith("+dirty")


def test_without_git_it_reports_what_the_sender_set(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_git(*args: object, **kwargs: object) -> None:
        raise FileNotFoundError("git")

    monkeypatch.setattr(checkpoints.subprocess, "run", no_git)
    monkeypatch.delenv("CEC_GIT_REV", raising=False)
    assert checkpoints.code_version() == "unknown"
    monkeypatch.setenv("CEC_GIT_REV", "abc1234")
    assert checkpoints.code_version(short=True) == "abc1234"
