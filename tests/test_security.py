"""Network security of the ZeroMQ endpoints (docs/security.md): CURVE between the ping
publisher and its subscribers with real key files and real sockets on loopback; key and
configuration errors that name the file; ``svss keys`` as a subprocess; and a source
rule: nothing deserialises with pickle or evaluates code."""

from __future__ import annotations

import ast
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zmq

from svss_daq import messages
from svss_daq.config import ConfigError, CurveConfig, DaqConfig, loads
from svss_daq.publisher import PingPublisher
from svss_daq.security import (
    generate_keys,
    load_key_file,
    secure_client,
    secure_server,
    stop_authenticator,
)
from svss_daq.subscriber import subscribe

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------ fixtures


@pytest.fixture
def keys(tmp_path):
    """A server pair, an authorized client pair and an unauthorized ('rogue') pair."""
    k = tmp_path / "keys"
    generate_keys(k / "server", "server")
    generate_keys(k / "client", "client")
    generate_keys(k / "rogue", "rogue")
    (k / "authorized").mkdir()
    (k / "authorized" / "client.key").write_bytes((k / "client" / "client.key").read_bytes())
    return k


def curve(k: Path, client: str = "client/client.key_secret", **over) -> CurveConfig:
    fields = {"enabled": True, "server_secret_key": str(k / "server/server.key_secret"),
              "authorized_clients": str(k / "authorized"),
              "server_public_key": str(k / "server/server.key"),
              "client_secret_key": str(k / client)}
    return CurveConfig(**{**fields, **over})


@pytest.fixture
def ctx():
    c = zmq.Context()
    yield c
    stop_authenticator(c)
    c.destroy(linger=0)


@pytest.fixture
def small_ping():
    from tests.test_messages import make_ping
    return lambda seq: make_ping(seq, nch=4, ns=64)


def _collect(pub: PingPublisher, subs: dict[str, zmq.Socket], make, seconds: float, *,
             until_received: bool = False) -> dict[str, list]:
    """Publish a ping every 10 ms for ``seconds`` (or, with ``until_received``, until
    every subscriber has one); what each subscriber decoded."""
    got = {name: [] for name in subs}
    deadline, seq = time.monotonic() + seconds, 0
    while time.monotonic() < deadline:
        pub.publish(make(seq))
        seq += 1
        time.sleep(0.01)
        for name, s in subs.items():
            while s.poll(0):
                got[name].append(messages.recv(s))
        if until_received and all(got.values()):
            break
    return got


# ---------------------------------------------------------------------- the wire


def test_only_an_authorized_subscriber_receives_pings(keys, ctx, small_ping):
    cfg = curve(keys)
    with PingPublisher("tcp://127.0.0.1:*", 100, ctx, curve=cfg, end_timeout_s=1) as pub:
        assert pub.secured
        subs = {
            "authorized": subscribe(pub.endpoint, 100, ctx, curve=cfg),
            "rogue": subscribe(pub.endpoint, 100, ctx,
                               curve=curve(keys, "rogue/rogue.key_secret")),
            "plain": subscribe(pub.endpoint, 100, ctx),
        }
        try:
            got = _collect(pub, subs, small_ping, seconds=2.0)
        finally:
            for s in subs.values():
                s.close(linger=0)
        assert pub.subscriptions == 1       # only the authorized one got through ZAP
    assert len(got["authorized"]) > 5
    seqs = [p.sequence for p in got["authorized"]]
    assert seqs == sorted(seqs)
    assert got["rogue"] == [] and got["plain"] == []


def test_disabled_or_absent_security_leaves_plain_zeromq(keys, ctx, small_ping):
    off = CurveConfig(False, "", "", "", "")     # disabled: the paths are not read
    with PingPublisher("tcp://127.0.0.1:*", 100, ctx, curve=off) as pub:
        assert not pub.secured
        sub = subscribe(pub.endpoint, 100, ctx, curve=None)
        try:
            got = _collect(pub, {"authorized": sub}, small_ping, seconds=5.0,
                           until_received=True)
        finally:
            sub.close(linger=0)
    assert got["authorized"]


def test_a_client_with_the_wrong_server_key_receives_nothing(keys, ctx, small_ping):
    cfg = curve(keys)
    # the client trusts the rogue's public key as the server's: the handshake fails
    wrong = curve(keys, server_public_key=str(keys / "rogue/rogue.key"))
    with PingPublisher("tcp://127.0.0.1:*", 100, ctx, curve=cfg) as pub:
        subs = {"authorized": subscribe(pub.endpoint, 100, ctx, curve=cfg),
                "wrong": subscribe(pub.endpoint, 100, ctx, curve=wrong)}
        try:
            got = _collect(pub, subs, small_ping, seconds=1.5)
        finally:
            for s in subs.values():
                s.close(linger=0)
    assert got["authorized"] and got["wrong"] == []


# ---------------------------------------------------------------------- key errors


def test_missing_key_files_are_named(keys, ctx):
    sock = ctx.socket(zmq.XPUB)
    try:
        missing = keys / "server/nothing.key_secret"
        with pytest.raises(ConfigError, match=f"{missing}: key file not found; expected a "
                           "secret key file"):
            secure_server(sock, curve(keys, server_secret_key=str(missing)))
        with pytest.raises(ConfigError, match="nowhere: authorized clients folder not "
                           "found"):
            secure_server(sock, curve(keys, authorized_clients=str(keys / "nowhere")))
        empty = keys / "empty"
        empty.mkdir()
        with pytest.raises(ConfigError, match=f"{empty}: no client public key files"):
            secure_server(sock, curve(keys, authorized_clients=str(empty)))
        with pytest.raises(ConfigError, match="server.key: key file not found"):
            secure_client(sock, curve(keys, server_public_key=str(keys / "server.key")))
    finally:
        sock.close(linger=0)


def test_a_public_key_file_is_not_a_secret_key(keys, ctx):
    public = keys / "client/client.key"
    with pytest.raises(ConfigError, match=f"{public}: no secret key; expected"):
        load_key_file(public, secret=True)
    sock = ctx.socket(zmq.SUB)
    try:
        with pytest.raises(ConfigError, match="no secret key"):
            secure_client(sock, curve(keys, client_secret_key=str(public)))
        with pytest.raises(ValueError, match="no secret key"):   # ConfigError is one
            secure_server(sock, curve(keys, server_secret_key=str(
                keys / "server/server.key")))
    finally:
        sock.close(linger=0)


def test_garbage_key_files_are_named(tmp_path, keys, ctx):
    bad = tmp_path / "bad.key_secret"
    bad.write_text("not a certificate\n")
    with pytest.raises(ConfigError, match=f"{bad}: no public key"):
        load_key_file(bad, secret=True)
    short = tmp_path / "short.key"
    short.write_text('curve\n    public-key = "abc"\n')
    with pytest.raises(ConfigError, match=f"{short}: public key is not a CURVE key"):
        load_key_file(short, secret=False)
    (tmp_path / "auth").mkdir()
    (tmp_path / "auth" / "x.key").write_text("junk\n")
    sock = ctx.socket(zmq.PUB)
    try:
        with pytest.raises(ConfigError, match="x.key: no public key; expected a public key "
                           "file"):
            secure_server(sock, curve(keys, authorized_clients=str(tmp_path / "auth")))
    finally:
        sock.close(linger=0)


def test_a_publisher_with_bad_keys_binds_nothing(keys, ctx):
    bad = curve(keys, server_secret_key=str(keys / "missing"))
    with pytest.raises(ConfigError, match="missing: key file not found"):
        PingPublisher("tcp://127.0.0.1:*", 10, ctx, curve=bad)
    with pytest.raises(ConfigError, match="missing: key file not found"):
        subscribe("tcp://127.0.0.1:5999", 10, ctx, curve=curve(keys, "missing"))


def test_relative_key_paths_resolve_against_the_config_folder(keys, tmp_path, ctx,
                                                             monkeypatch):
    monkeypatch.setenv("SVSS_CONFIG_DIR", str(keys))
    rel = CurveConfig(True, "server/server.key_secret", "authorized", "server/server.key",
                      "client/client.key_secret")
    pub, sub = ctx.socket(zmq.PUB), ctx.socket(zmq.SUB)
    try:
        secure_server(pub, rel)
        secure_client(sub, rel)
        assert pub.getsockopt(zmq.CURVE_SERVER) == 1
        assert pub.getsockopt(zmq.MECHANISM) == sub.getsockopt(zmq.MECHANISM) == zmq.CURVE
    finally:
        pub.close(linger=0)
        sub.close(linger=0)


# ------------------------------------------------------------------ configuration


DAQ = """
[publisher]
endpoint = "tcp://127.0.0.1:5556"
send_hwm = 10
[subscriber]
receive_hwm = 10
[recorder]
flush_every_pings = 1
flush_interval_s = 1.0
"""


def test_the_security_table_is_optional_and_validated():
    assert loads(DaqConfig, DAQ).security is None
    cfg = loads(DaqConfig, DAQ + '[security]\nenabled = true\nserver_secret_key = "a"\n'
                'authorized_clients = "b"\nserver_public_key = "c"\n'
                'client_secret_key = "d"\n')
    assert cfg.security == CurveConfig(True, "a", "b", "c", "d")
    with pytest.raises(ConfigError, match="daq.toml: missing key 'security.enabled'"):
        loads(DaqConfig, DAQ + "[security]\n", "daq.toml")
    with pytest.raises(ConfigError, match="daq.toml: key 'security.enabled'"):
        loads(DaqConfig, DAQ + '[security]\nenabled = "yes"\n', "daq.toml")


def test_the_shipped_daq_toml_leaves_security_off():
    from svss_daq.config import load
    sec = load(DaqConfig, ROOT / "config" / "daq.toml").security
    assert sec is None or sec.enabled is False


# --------------------------------------------------------------------- svss keys


def test_svss_keys_writes_a_usable_pair_with_a_private_secret(tmp_path, ctx, small_ping):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = tmp_path / "k"
    for name in ("server", "laptop"):
        res = subprocess.run([sys.executable, "-m", "svss", "keys", "--out", str(out),
                              "--name", name], capture_output=True, text=True, env=env,
                             timeout=60, check=False)
        assert res.returncode == 0, res.stderr
        assert f"{name}.key_secret" in res.stdout
    assert "authorized_clients" in res.stdout or "authorized" in res.stdout
    for name in ("server", "laptop"):
        assert stat.S_IMODE((out / f"{name}.key_secret").stat().st_mode) == 0o600
        assert not stat.S_IMODE((out / f"{name}.key").stat().st_mode) & 0o022
    again = subprocess.run([sys.executable, "-m", "svss", "keys", "--out", str(out)],
                           capture_output=True, text=True, env=env, timeout=60, check=False)
    assert again.returncode == 2 and "server.key: exists" in again.stderr

    (tmp_path / "auth").mkdir()
    (tmp_path / "auth" / "laptop.key").write_bytes((out / "laptop.key").read_bytes())
    cfg = CurveConfig(True, str(out / "server.key_secret"), str(tmp_path / "auth"),
                      str(out / "server.key"), str(out / "laptop.key_secret"))
    with PingPublisher("tcp://127.0.0.1:*", 100, ctx, curve=cfg) as pub:
        sub = subscribe(pub.endpoint, 100, ctx, curve=cfg)
        try:
            got = _collect(pub, {"authorized": sub}, small_ping, seconds=5.0,
                           until_received=True)
        finally:
            sub.close(linger=0)
    assert got["authorized"]


# --------------------------------------------------- no pickle, no eval: the rule


UNSAFE_MODULES = {"pickle", "_pickle", "cPickle", "cloudpickle", "dill", "jsonpickle",
                  "marshal", "shelve"}
UNSAFE_CALLS = {"eval", "exec"}
UNSAFE_ATTRIBUTES = {"send_pyobj", "recv_pyobj", "read_pickle", "to_pickle",
                     "unsafe_load", "full_load"}

#: reviewed exceptions: (file, finding) -> why it is not on the wire or in a file
ALLOWED = {
    ("svss_daq/untrusted_hdf5.py", "import pickle"):
        "in_child: the result of a read passes from the process's own fork to it over "
        "an os.pipe; the bytes are written by pickle.dumps in that fork, never read "
        "from a file or a socket",
    ("svss_proc/products_process.py", "import pickle"):
        "a finished tile passes from the live worker to the products process it spawned "
        "itself, over that child's multiprocessing queue (an os.pipe); the bytes are "
        "written by pickle.dumps in the worker, never read from a file or a socket",
}


def unsafe_uses(path: Path) -> list[str]:
    """Deserialisation or evaluation of data in a module: pickle-like imports, eval and
    exec, pyzmq's pickle helpers, yaml.load and allow_pickle=True."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [f"import {a.name}" for a in node.names
                      if a.name.split(".")[0] in UNSAFE_MODULES]
        elif isinstance(node, ast.ImportFrom) and node.module and \
                node.module.split(".")[0] in UNSAFE_MODULES:
            found.append(f"import {node.module}")
        elif isinstance(node, ast.Call):
            fn = node.func
            if isinstance(fn, ast.Name) and fn.id in UNSAFE_CALLS:
                found.append(f"{fn.id}()")
            if isinstance(fn, ast.Attribute):
                if fn.attr in UNSAFE_ATTRIBUTES:
                    found.append(f".{fn.attr}()")
                if fn.attr == "load" and isinstance(fn.value, ast.Name) and \
                        fn.value.id == "yaml":
                    found.append("yaml.load()")
            for kw in node.keywords:
                if kw.arg == "allow_pickle" and not (
                        isinstance(kw.value, ast.Constant) and kw.value.value is False):
                    found.append("allow_pickle=")
    return found


def test_the_unsafe_use_checker_sees_them(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""Never pickle, never eval."""\nimport numpy as np, yaml\n'
                 "from pickle import loads\nimport marshal\n"
                 "def f(s, b):\n    eval(b)\n    exec(b)\n    s.recv_pyobj()\n"
                 "    yaml.load(b)\n    yaml.safe_load(b)\n"
                 "    np.load(b, allow_pickle=True)\n    np.load(b, allow_pickle=False)\n"
                 "    np.load(b)\n    model.eval()\n")
    assert sorted(unsafe_uses(f)) == sorted(["import pickle", "import marshal", "eval()",
                                             "exec()", ".recv_pyobj()", "yaml.load()",
                                             "allow_pickle="])


@pytest.mark.parametrize("package", ["svss_daq", "svss_proc", "svss", "sim_device"])
def test_no_pickle_or_eval_in_the_code(package):
    files = sorted((ROOT / package).rglob("*.py"))
    assert files
    offenders = {}
    for f in files:
        rel = str(f.relative_to(ROOT))
        bad = [u for u in unsafe_uses(f) if (rel, u) not in ALLOWED]
        if bad:
            offenders[rel] = bad
    assert not offenders, (f"pickle/eval-like use (docs/security.md: no pickle or eval "
                           f"on the wire or in files): {offenders}")
