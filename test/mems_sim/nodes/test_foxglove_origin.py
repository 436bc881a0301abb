"""The live view's Origin rule: loopback pages, the Foxglove web app, desktop apps and
programs are allowed; any other web page is refused unless the user names its origin."""

from __future__ import annotations

import pytest

from mems_sim.nodes.foxglove_origin import OriginError, OriginPolicy, parse_origins

ALLOWED = [
    None,  # a program, not a page: no Origin header
    "null",
    "file://",
    "file:///home/user/view.html",
    "http://localhost",
    "http://localhost:3000",
    "https://LOCALHOST:8443/",
    "http://127.0.0.1:8080",
    "http://127.1.2.3",
    "http://[::1]:5173",
    "https://app.foxglove.dev",
    "HTTPS://App.Foxglove.Dev",
]
REFUSED = [
    "https://evil.example",
    "http://localhost.evil.example",
    "http://127.0.0.1.evil.example",
    "https://app.foxglove.dev.evil.example",
    "http://app.foxglove.dev",  # not the web app's scheme
    "ws://localhost:8765",  # not a page's scheme
    "http://192.168.1.10:8080",
    "http://[::ffff:10.0.0.1]",
    "http://[::1",  # unparseable
    "",
]


@pytest.mark.parametrize("origin", ALLOWED)
def test_default_policy_allows(origin):
    assert OriginPolicy().allows(origin)


@pytest.mark.parametrize("origin", REFUSED)
def test_default_policy_refuses(origin):
    assert not OriginPolicy().allows(origin)


def test_a_named_origin_is_allowed_and_only_that_one():
    policy = OriginPolicy(parse_origins(" https://Viewer.Lab.example:8443/ , http://10.0.0.5 "))
    assert policy.allows("https://viewer.lab.example:8443")
    assert policy.allows("http://10.0.0.5")
    assert not policy.allows("https://viewer.lab.example")  # another port: another origin
    assert not policy.allows("http://10.0.0.6")
    assert parse_origins("") == ()


@pytest.mark.parametrize(
    "text",
    [
        "viewer.example",
        "https://viewer.example/path",
        "https://u@viewer.example",
        "https://",
        "http://h:port",
    ],
)
def test_a_named_origin_must_be_scheme_host_port(text):
    with pytest.raises(OriginError, match="not an origin"):
        parse_origins(f"https://ok.example,{text}")
