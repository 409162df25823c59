"""ZeroMQ CURVE security for the SVSS endpoints (the ``[security]`` table of daq.toml).

Every endpoint binds to loopback unless configured otherwise (:mod:`.endpoints` warns on
any other bind). A link that leaves the boat is secured with ZeroMQ CURVE: the server
socket (ping publisher, status stream, catch-up service) holds the server's key pair and
admits only the clients whose public keys lie in the ``authorized_clients`` folder; a
client socket holds its own key pair and the server's public key. A client without an
authorized key never completes the handshake and receives nothing.

Usage: ``secure_server(sock, curve)`` before ``sock.bind``, ``secure_client(sock, curve)``
before ``sock.connect``. Both are no-ops when ``curve`` is None or disabled.

Key files are ZeroMQ "zcert" files as written by :func:`zmq.auth.create_certificates`
(``svss keys``): ``NAME.key`` holds the public key, ``NAME.key_secret`` both keys.
Relative key paths resolve against the configuration folder (``--config-dir``,
``$SVSS_CONFIG_DIR`` or the project's ``config/``: where daq.toml lives); ``~`` is
expanded. See docs/security.md.
"""

from __future__ import annotations

import atexit
import hashlib
import logging
import os
import threading
from pathlib import Path

import zmq
import zmq.auth
import zmq.utils.z85
from zmq.auth.thread import ThreadAuthenticator

from .config import ConfigError, CurveConfig, config_dir

log = logging.getLogger(__name__)

PUBLIC_SUFFIX = ".key"
SECRET_SUFFIX = ".key_secret"
_Z85_KEY_CHARS = 40   # a 32-byte CURVE key in Z85


def _active(curve: CurveConfig | None) -> bool:
    if curve is None:
        return False
    if not isinstance(curve, CurveConfig):
        raise TypeError(f"curve: expected a CurveConfig or None, got {type(curve).__name__}")
    return curve.enabled


def resolve_path(path: str, what: str) -> Path:
    """A key path of the ``[security]`` table: ``~`` expanded, relative paths against the
    configuration folder."""
    if not isinstance(path, str) or not path.strip():
        raise ConfigError(f"security.{what}: expected a file or folder path, got {path!r}")
    p = Path(path).expanduser()
    return p if p.is_absolute() else config_dir() / p


def _check_key(key: bytes | None, file: Path, which: str) -> bytes:
    if key is None:
        raise ConfigError(f"{file}: no {which} key; expected a ZeroMQ key file "
                          f"(zcert, 'svss keys') with a {which}-key line")
    try:
        if len(key) != _Z85_KEY_CHARS:
            raise ValueError(f"{len(key)} characters")
        zmq.utils.z85.decode(key)
    except ValueError as exc:
        raise ConfigError(f"{file}: {which} key is not a CURVE key ({exc}); expected "
                          f"{_Z85_KEY_CHARS} Z85 characters") from None
    return key


def load_key_file(path: str | os.PathLike, *, secret: bool) -> tuple[bytes, bytes | None]:
    """(public, secret) keys of a zcert file; ``secret=True`` requires the secret key.

    Raises :class:`~svss_daq.config.ConfigError` naming the file and what was expected.
    """
    file = Path(path)
    expected = ("a secret key file (NAME.key_secret, written by 'svss keys')" if secret
                else "a public key file (NAME.key, written by 'svss keys')")
    if not file.is_file():
        raise ConfigError(f"{file}: key file not found; expected {expected}")
    try:
        public, secret_key = zmq.auth.load_certificate(file)
    except OSError as exc:
        raise ConfigError(f"{file}: cannot read the key file ({exc}); expected "
                          f"{expected}") from None
    except ValueError:
        raise ConfigError(f"{file}: no public key; expected {expected}") from None
    _check_key(public, file, "public")
    if secret:
        _check_key(secret_key, file, "secret")
        mode = file.stat().st_mode & 0o777
        if mode & 0o077:
            log.warning("%s: secret key file is readable by others (mode %o); "
                        "chmod 600 it", file, mode)
    return public, secret_key


def _authorized_keys(folder: Path) -> int:
    """Check the authorized-clients folder; return how many public keys it holds."""
    if not folder.is_dir():
        raise ConfigError(f"{folder}: authorized clients folder not found; expected a "
                          f"folder of client public key files (*{PUBLIC_SUFFIX})")
    files = sorted(folder.glob(f"*{PUBLIC_SUFFIX}"))
    for f in files:
        load_key_file(f, secret=False)
    if any(folder.glob(f"*{SECRET_SUFFIX}")):
        log.warning("%s: holds secret key files (*%s); only client public keys belong "
                    "there", folder, SECRET_SUFFIX)
    if not files:
        raise ConfigError(f"{folder}: no client public key files (*{PUBLIC_SUFFIX}); "
                          "expected at least one (copy each client's NAME.key here)")
    return len(files)


# One ZAP authenticator per context, with one ZAP domain per authorized-clients folder.
_auth_lock = threading.Lock()
_authenticators: dict[int, tuple[zmq.Context, ThreadAuthenticator]] = {}


def _domain(folder: Path) -> str:
    return "svss-" + hashlib.sha256(str(folder).encode()).hexdigest()[:16]


def _authenticator(ctx: zmq.Context) -> ThreadAuthenticator:
    with _auth_lock:
        entry = _authenticators.get(id(ctx))
        if entry is not None and entry[0] is ctx and entry[1].is_alive():
            return entry[1]
        auth = ThreadAuthenticator(ctx, log=logging.getLogger(__name__ + ".zap"))
        auth.start()
        _authenticators[id(ctx)] = (ctx, auth)
        return auth


def stop_authenticator(ctx: zmq.Context | None = None) -> None:
    """Stop the ZAP authenticator of ``ctx`` (default: every one started here). Call it
    before ``ctx.term()``: the authenticator's sockets keep a context alive."""
    with _auth_lock:
        keys = [k for k, (c, _) in _authenticators.items() if ctx is None or c is ctx]
        entries = [_authenticators.pop(k) for k in keys]
    for _, auth in entries:
        auth.stop()


atexit.register(stop_authenticator)


def secure_server(sock: zmq.Socket, curve: CurveConfig | None) -> None:
    """Make ``sock`` a CURVE server admitting only the keys in ``authorized_clients``.

    Call before ``sock.bind``. A no-op when ``curve`` is None or disabled. Starts the
    context's ZAP authenticator once; the authorized keys are read now (restart the
    server after adding or removing one).
    """
    if not _active(curve):
        return
    secret_file = resolve_path(curve.server_secret_key, "server_secret_key")
    folder = resolve_path(curve.authorized_clients, "authorized_clients").resolve()
    public, secret = load_key_file(secret_file, secret=True)
    n = _authorized_keys(folder)
    domain = _domain(folder)
    auth = _authenticator(sock.context)
    auth.configure_curve(domain=domain, location=str(folder))
    sock.setsockopt_string(zmq.ZAP_DOMAIN, domain)
    sock.setsockopt(zmq.CURVE_SECRETKEY, secret)
    sock.setsockopt(zmq.CURVE_PUBLICKEY, public)
    sock.setsockopt(zmq.CURVE_SERVER, 1)
    log.info("CURVE server: key %s, %d authorized client key(s) in %s", secret_file, n,
             folder)


def secure_client(sock: zmq.Socket, curve: CurveConfig | None) -> None:
    """Give ``sock`` this client's CURVE key pair and the server's public key.

    Call before ``sock.connect``. A no-op when ``curve`` is None or disabled.
    """
    if not _active(curve):
        return
    server_file = resolve_path(curve.server_public_key, "server_public_key")
    client_file = resolve_path(curve.client_secret_key, "client_secret_key")
    server_public, _ = load_key_file(server_file, secret=False)
    public, secret = load_key_file(client_file, secret=True)
    sock.setsockopt(zmq.CURVE_SERVERKEY, server_public)
    sock.setsockopt(zmq.CURVE_PUBLICKEY, public)
    sock.setsockopt(zmq.CURVE_SECRETKEY, secret)
    log.info("CURVE client: key %s, server key %s", client_file, server_file)


def generate_keys(out_dir: str | os.PathLike, name: str, *, overwrite: bool = False
                  ) -> tuple[Path, Path]:
    """Write a new CURVE key pair ``out_dir/NAME.key`` (public, mode 0644) and
    ``out_dir/NAME.key_secret`` (mode 0600); return their paths. Refuses to replace
    existing files unless ``overwrite``."""
    if not name or not name.replace("-", "").replace("_", "").replace(".", "").isalnum() \
            or name.startswith("."):
        raise ValueError(f"key name {name!r}: expected letters, digits, '-', '_' or '.'")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    public, secret = out / f"{name}{PUBLIC_SUFFIX}", out / f"{name}{SECRET_SUFFIX}"
    for f in (public, secret):
        if f.exists() and not overwrite:
            raise FileExistsError(f"{f}: exists; refusing to replace a key (use --force)")
    # Create the secret file 0600 first: create_certificates rewrites it in place, so it
    # is never readable by others, even briefly.
    fd = os.open(secret, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
    finally:
        os.close(fd)
    pub, sec = zmq.auth.create_certificates(out, name)
    os.chmod(sec, 0o600)
    os.chmod(pub, 0o644)
    return Path(pub), Path(sec)
