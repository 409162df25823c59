"""``svss view``'s place in the configuration: acquire.toml ``[view]`` (its defaults
written once, in ViewSection), and the endpoints' bind rules applied to its address."""

from __future__ import annotations

import logging
import re

import pytest

from svss.view.server import http_address
from svss_daq.acquire_config import AcquireConfig, ViewSection, view_section
from svss_daq.config import ConfigError, config_path, loads, omitted_default


def without_view(text: str) -> str:
    """acquire.toml's text without its [view] table (comments and keys)."""
    out = re.sub(r"\[view\]\n(?:(?:#.*|\w+ *=.*)?\n)*?(?=\[)", "", text)
    assert "[view]" not in out and "[disk]" in out
    return out


def test_view_defaults_are_loopback_and_written_once():
    text = config_path("acquire.toml").read_text()
    shipped = view_section(loads(AcquireConfig, text, "acquire.toml"))
    assert shipped == ViewSection(omitted_default(ViewSection, "address"),
                                  omitted_default(ViewSection, "port"))
    assert shipped.address == "127.0.0.1"
    # no [view] table at all: the same
    bare = without_view(text)
    assert view_section(loads(AcquireConfig, bare, "bare.toml")) == shipped
    changed = loads(AcquireConfig, bare + "[view]\nport = 9000\n", "x.toml")
    assert view_section(changed) == ViewSection("127.0.0.1", 9000)


def test_a_bad_port_names_the_key():
    bare = without_view(config_path("acquire.toml").read_text())
    with pytest.raises(ConfigError, match="port"):
        loads(AcquireConfig, bare + "[view]\nport = 70000\n", "x.toml")


def test_the_bind_rules_of_the_endpoints_apply(caplog):
    assert http_address("127.0.0.1", 8558) == ("127.0.0.1", 8558)
    assert http_address("::1", 0) == ("::1", 0)          # 0: a free port
    with caplog.at_level(logging.WARNING):
        assert http_address("0.0.0.0", 8558) == ("0.0.0.0", 8558)
    assert "every network interface" in caplog.text
    with pytest.raises(ValueError, match="not an address or host name"):
        http_address("bad host!", 8558)
    with pytest.raises(ValueError, match="1..65535"):
        http_address("127.0.0.1", 70000)
