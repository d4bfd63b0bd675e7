"""ovis.common.view.guard: origins, token strength, the back-off on wrong tokens, the
log throttle and the seats, with a clock of our own."""

from __future__ import annotations

import math

import pytest

from ovis.common.view.guard import (
    FREE_GUESSES,
    MAX_BACKOFF_S,
    GuessLimiter,
    LogThrottle,
    OriginPolicy,
    Seats,
    canonical_origin,
    new_token,
    token_bits,
    token_problem,
)
from ovis.common.view.settings import view_settings


def test_token_strength_is_length_times_the_classes_it_uses() -> None:
    assert token_bits("0123456789abcdef") == pytest.approx(16 * math.log2(10 + 26))
    assert token_bits("a" * 28) == pytest.approx(28 * math.log2(26))  # 131 bits: an upper bound
    assert token_bits("Ab1-") == pytest.approx(4 * math.log2(10 + 26 + 26 + 33))
    assert token_bits("") == 0.0
    assert token_problem("0123456789abcdef") is not None  # the 16 characters
    assert token_problem("short") is not None
    for _ in range(50):
        made = new_token()
        assert len(made) == 32 and token_problem(made) is None
    assert view_settings(operator_token=new_token()).operator_token
    with pytest.raises(ValueError, match="worth at most 83 bits, 128 are needed"):
        view_settings(operator_token="0123456789abcdef")


def test_origins_are_compared_in_one_form() -> None:
    assert canonical_origin("HTTP://Example.ORG") == "http://example.org:80"
    assert canonical_origin("https://example.org") == "https://example.org:443"
    assert canonical_origin("http://[::1]:8080") == "http://[::1]:8080"
    for bad in ("null", "file://x", "http://a/b/c", "example.org", "http://a:99999", ""):
        assert canonical_origin(bad) is None, bad
    with pytest.raises(ValueError, match="allow_origins"):
        view_settings(allow_origins=["example.org"])


def test_a_loopback_view_takes_its_own_names_only() -> None:
    policy = OriginPolicy("127.0.0.1", 8080)
    for own in ("http://127.0.0.1:8080", "http://localhost:8080", "http://[::1]:8080"):
        assert policy.problem(own, "127.0.0.1:8080", required=True) is None, own
    for other in ("http://127.0.0.1:8081", "https://127.0.0.1:8080", "http://evil.example"):
        assert "is not allowed" in policy.problem(other, "127.0.0.1:8080", required=True)
    # DNS rebinding: a page of evil.example:8080 resolved to 127.0.0.1 asks Host evil…
    assert policy.problem("http://evil.example:8080", "evil.example:8080", required=True)
    assert "no Origin header" in policy.problem(None, "127.0.0.1:8080", required=True)
    assert policy.problem(None, "127.0.0.1:8080", required=False) is None
    allowing = OriginPolicy("127.0.0.1", 8080, ["https://ovis.example.org"])
    assert allowing.problem("https://ovis.example.org", None, required=True) is None


def test_a_view_on_every_address_takes_the_host_the_page_was_loaded_from() -> None:
    policy = OriginPolicy("0.0.0.0", 8080)
    assert policy.problem("http://10.0.0.5:8080", "10.0.0.5:8080", required=True) is None
    assert policy.problem("http://lab-pc:8080", "lab-pc:8080", required=True) is None
    assert policy.problem("http://evil.example", "10.0.0.5:8080", required=True)
    assert policy.problem("http://10.0.0.5:8080", None, required=True)


def test_wrong_tokens_make_a_client_wait_longer_and_longer() -> None:
    now = [1000.0]  # a clock that moves only when told
    guesses = GuessLimiter(lambda: now[0])
    waits = [guesses.wrong("10.0.0.9") for _ in range(FREE_GUESSES + 8)]
    assert waits[:FREE_GUESSES] == [0.0] * FREE_GUESSES
    assert waits[FREE_GUESSES:] == [1.0, 2.0, 4.0, 8.0, 16.0, 32.0, MAX_BACKOFF_S, MAX_BACKOFF_S]
    assert guesses.wait_s("10.0.0.9") == MAX_BACKOFF_S
    assert guesses.wait_s("10.0.0.8") == 0.0  # another client is not slowed down
    now[0] += 59.5
    assert guesses.wait_s("10.0.0.9") == pytest.approx(0.5)
    guesses.right("10.0.0.9")
    assert guesses.wait_s("10.0.0.9") == 0.0 and guesses.wrong("10.0.0.9") == 0.0


def test_refusals_are_logged_once_per_period_with_the_count_left_out() -> None:
    now = [1000.0]
    throttle = LogThrottle(10.0, lambda: now[0])
    said = [throttle.allow("token") for _ in range(1000)]
    assert said[0] == 0 and said[1:] == [None] * 999
    assert throttle.allow("origin") == 0  # another kind has its own line
    now[0] += 10.0
    assert throttle.allow("token") == 999


def test_seats_per_client_and_in_all_and_the_operators_own() -> None:
    seats = Seats(total=4, per_client=2, operator_seats=1)
    assert [seats.take("a") for _ in range(3)][2].startswith("too many viewers from a (2,")
    assert seats.take("b") is None and seats.take("b") is None
    assert seats.take("c").startswith("too many viewers (4,")
    assert seats.take_operator() is None
    assert "operator seats are taken" in seats.take_operator()
    seats.leave("a", operator=False)
    assert seats.take("c") is None
    seats.leave("x", operator=True)
    assert seats.take_operator() is None
