"""A session's teleop tokens are derived from the session id and a server secret kept in a
0600 file: the same on every start, different per session and per purpose."""

from __future__ import annotations

import stat

import pytest

from crowdteleop.coord.guard.session_keys import SessionKeys, SessionSecretError


def test_tokens_are_stable_across_starts_and_distinct_per_session_and_purpose(tmp_path):
    path = tmp_path / "session.key"
    first = SessionKeys.load_or_create(path)
    again = SessionKeys.load_or_create(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert [p.name for p in tmp_path.iterdir()] == ["session.key"], "no staging file left"
    tokens = {
        first.teleop_token("s_1"),
        first.teleop_admin_token("s_1"),
        first.teleop_token("s_2"),
        first.teleop_admin_token("s_2"),
    }
    assert len(tokens) == 4
    assert again.teleop_token("s_1") == first.teleop_token("s_1")
    assert all(len(token) >= 40 for token in tokens), "256-bit HMACs, URL-safe"


def test_another_secret_gives_other_tokens(tmp_path):
    mine = SessionKeys.load_or_create(tmp_path / "a.key")
    theirs = SessionKeys.load_or_create(tmp_path / "b.key")
    assert mine.teleop_token("s_1") != theirs.teleop_token("s_1")


def test_a_readable_secret_file_is_tightened_and_a_foreign_one_refused(tmp_path):
    path = tmp_path / "session.key"
    SessionKeys.load_or_create(path)
    path.chmod(0o644)
    SessionKeys.load_or_create(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    path.write_text("not hex")
    with pytest.raises(SessionSecretError, match="delete it to make a new one"):
        SessionKeys.load_or_create(path)
