"""trq_lab.campaign.cli: the progress bar (tqdm) reads as lines in a log, and the command's
options."""

from __future__ import annotations

import io

import pytest

from trq_lab.campaign import cli

tqdm = pytest.importorskip("tqdm")


def test_progress_in_a_log_is_lines_without_carriage_returns():
    log = io.StringIO()                     # not a TTY, as in CI
    with cli.progress_bar(tqdm, 3, log) as bar:
        for failed in range(3):
            bar.set_postfix_str(f"{failed} failed", refresh=False)
            bar.update(1)
    text = log.getvalue()
    assert "\r" not in text and text.endswith("\n")
    assert "3/3 flights, 2 failed" in text.splitlines()[-1]


def test_dry_run_lists_the_flights(capsys):
    assert cli.main(["smoke", "--out", "unused", "--dry-run"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == "campaign: smoke: 8 flights"
