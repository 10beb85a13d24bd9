"""``solidkit label serve``'s address and token handling (the server itself: tests/labeling)."""

from __future__ import annotations

import pytest

from solidkit.cli.label import app_url, read_token
from solidkit.errors import InputError


@pytest.mark.parametrize(
    ("host", "url"),
    [
        ("127.0.0.1", "http://127.0.0.1:8765/"),
        ("localhost", "http://localhost:8765/"),
        ("::1", "http://[::1]:8765/"),
        ("[::1]", "http://[::1]:8765/"),
        ("0.0.0.0", "http://127.0.0.1:8765/"),
        ("::", "http://127.0.0.1:8765/"),
        ("fe80::2", "http://[fe80::2]:8765/"),
    ],
)
def test_the_printed_address_is_a_valid_url(host, url):
    assert app_url(host, 8765) == url


def test_the_token_is_read_from_a_file_and_bad_files_are_clear_errors(tmp_path):
    f = tmp_path / "token"
    f.write_text("  s3cret-token-of-24-chars \nignored\n")
    assert read_token(f) == "s3cret-token-of-24-chars"
    (tmp_path / "empty").write_text("\n")
    with pytest.raises(InputError, match="empty"):
        read_token(tmp_path / "empty")
    with pytest.raises(InputError, match="cannot read"):
        read_token(tmp_path / "missing")


def test_a_token_given_twice_is_refused(tmp_path, cli, monkeypatch):
    camp = tmp_path / "camp"
    camp.mkdir()
    (camp / "manifest.json").write_text("{}")
    (tmp_path / "token").write_text("0123456789abcdef0123\n")
    monkeypatch.setenv("SOLIDKIT_LABEL_TOKEN", "another-token-of-enough-length")
    code, _, err = cli("label", "serve", str(camp), "--token-file", str(tmp_path / "token"))
    assert code == 2 and "give the token once" in err
