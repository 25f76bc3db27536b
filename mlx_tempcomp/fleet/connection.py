"""
Who the fleet's client is to a Dask scheduler: its TLS certificates, and a refusal in one line.

The client's certificates come as the ``dask`` command line takes them
(``--tls-ca-file``, ``--tls-cert``, ``--tls-key``) or from Dask's own
configuration (``distributed.comm.tls.ca-file``, ``.client.cert``,
``.client.key``: a YAML file in ~/.config/dask, or ``DASK_DISTRIBUTED__...``
variables), an option overriding its key; distributed's `Security` reads
both and builds the TLS context. `scheduler_client` checks what can be
checked before connecting (a tls:// scheduler without certificates, a
certificate file that does not load, options for a scheduler in clear), then
connects within Dask's ``distributed.comm.timeouts.connect``; every refusal
is a `UserError` of one line naming the setting to change, never a
traceback. The local cluster runs in clear on 127.0.0.1: TLS options or
Dask's ``distributed.comm.require-encryption`` without a scheduler are
refused (`check_local`). Dask is imported inside the functions.
"""

from dataclasses import dataclass
import ssl

from .unit import one_line
from ..toolkit.errors import UserError

CONNECT_TIMEOUT = 'distributed.comm.timeouts.connect'
REQUIRE_ENCRYPTION = 'distributed.comm.require-encryption'
# Each client setting: its dask command-line option, Security's field, Dask's configuration key.
SETTINGS = (('--tls-ca-file', 'tls_ca_file', 'distributed.comm.tls.ca-file'),
            ('--tls-cert', 'tls_client_cert', 'distributed.comm.tls.client.cert'),
            ('--tls-key', 'tls_client_key', 'distributed.comm.tls.client.key'))


def _join(names) -> str:
    """Give 'a', 'a and b', 'a, b and c'."""
    names = list(names)
    return ', '.join(names[:-1]) + f' and {names[-1]}' if len(names) > 1 else names[0]


OPTIONS = _join(option for option, _, _ in SETTINGS)
# A scheduler that refuses the client's certificate says why in its TLS alert, or just hangs up.
_CLIENT_REFUSED = (('ALERT_UNKNOWN_CA', 'signed by a CA it does not trust'),
                   ('ALERT_CERTIFICATE_EXPIRED', 'expired'),
                   ('ALERT_BAD_CERTIFICATE', 'a bad certificate'),
                   ('ALERT_CERTIFICATE_UNKNOWN', 'not accepted'),
                   ('EOF occurred in violation of protocol', 'closed in the TLS handshake'))
# What loading the TLS files says (ssl's reasons), as the user's words.
_LOAD_REASONS = {'NO_CERTIFICATE_OR_CRL_FOUND': 'the CA file holds no certificate',
                 'KEY_VALUES_MISMATCH': "the key is not the certificate's",
                 'PEM lib': 'a certificate or key that is not PEM'}


@dataclass(frozen=True)
class TlsOptions:
    """The client's TLS files given on the command line (None: Dask's configuration's)."""

    ca_file: str = None
    cert: str = None
    key: str = None

    def given(self) -> dict:
        """Give {Security field: path} of the options given."""
        values = (self.ca_file, self.cert, self.key)
        return {field: value for (_, field, _), value in zip(SETTINGS, values)
                if value is not None}


def _label(tls: TlsOptions, field: str) -> str:
    """Name where a setting comes from: the option if given, else Dask's configuration key."""
    option, _, key = next(setting for setting in SETTINGS if setting[1] == field)
    return option if field in tls.given() else key


def _either(tls: TlsOptions, fields) -> str:
    """Name the settings of ``fields`` both ways: the options, or Dask's configuration."""
    settings = [setting for setting in SETTINGS if setting[1] in fields]
    return (f'{_join(option for option, _, _ in settings)} (or '
            f"{_join(key for _, _, key in settings)} in Dask's configuration)")


def check_local(tls: TlsOptions) -> None:
    """Refuse TLS for the local cluster, which runs in clear on 127.0.0.1 (UserError)."""
    import dask
    if tls.given():
        msg = (f'{OPTIONS} are the certificates of a tls:// scheduler: give --scheduler '
               'tls://HOST:PORT too (without it the fleet runs on a local cluster, in clear '
               'on 127.0.0.1)')
        raise UserError(msg)
    if dask.config.get(REQUIRE_ENCRYPTION, None):
        msg = (f"Dask's configuration requires encryption ({REQUIRE_ENCRYPTION}) and the "
               'local cluster runs in clear on 127.0.0.1: give --scheduler tls://HOST:PORT, '
               f'or set {REQUIRE_ENCRYPTION} to False')
        raise UserError(msg)


def _security(address: str, tls: TlsOptions):
    """Give distributed's Security for ``address``: the options over Dask's configuration."""
    from distributed import Security
    from distributed.comm.addressing import parse_address
    try:
        scheme = parse_address(address)[0]
        security = Security(require_encryption=True if tls.given() else None, **tls.given())
    except ValueError as err:  # not an address, or a TLS version Dask does not know
        msg = f'scheduler {address}: {one_line(err)}'
        raise UserError(msg) from None
    if scheme != 'tls':
        if tls.given():
            msg = (f'scheduler {address}: {OPTIONS} are for a tls:// scheduler; give it as '
                   'tls://HOST:PORT')
            raise UserError(msg)
        if security.require_encryption:
            msg = (f"scheduler {address}: Dask's configuration requires encryption "
                   f'({REQUIRE_ENCRYPTION}): give it as tls://HOST:PORT')
            raise UserError(msg)
        return security
    # Dask's TLS context needs the CA and a certificate; the key may be in the certificate's file.
    missing = [field for _, field, _ in SETTINGS[:2] if not getattr(security, field)]
    if missing:
        named = _either(tls, [field for _, field, _ in SETTINGS] if len(missing) == 2 else missing)
        msg = f'scheduler {address} needs TLS: give {named}{" too" if len(missing) == 1 else ""}'
        raise UserError(msg)
    _check_files(address, tls, security)
    return security


def _check_files(address: str, tls: TlsOptions, security) -> None:
    """Read the client's TLS files, then load them as distributed will; UserError if not."""
    paths = {field: getattr(security, field) for _, field, _ in SETTINGS
             if getattr(security, field)}
    for field, path in paths.items():
        if '\n' in path:  # Security takes PEM text in place of a file name too
            continue
        try:
            with open(path, 'rb'):
                pass
        except OSError as err:
            msg = f'scheduler {address}: {_label(tls, field)} {path}: {err.strerror}'
            raise UserError(msg) from None
    try:
        security.get_connection_args('client')
    except ssl.SSLError as err:
        reason = _LOAD_REASONS.get(err.reason or '', one_line(err))
        named = ', '.join(f'{_label(tls, field)} {path}' for field, path in paths.items())
        msg = f'scheduler {address}: the TLS files do not load ({reason}): {named}'
        raise UserError(msg) from None


def _chain(err: BaseException) -> list:
    """Give an error and those behind it (cause, context, a closed stream's real error)."""
    seen = []
    while err is not None and err not in seen:
        seen.append(err)
        err = err.__cause__ or err.__context__ or getattr(err, 'real_error', None)
    return seen


def refusal(address: str, tls: TlsOptions, err: BaseException) -> str:
    """Give the one line that says why the scheduler at ``address`` cannot be used."""
    import dask
    from dask.utils import parse_timedelta
    chain = _chain(err)
    text = ' '.join(str(link) for link in chain)
    verify = next((link for link in chain if isinstance(link, ssl.SSLCertVerificationError)),
                  None)
    if verify is not None:
        dated = any(word in verify.verify_message for word in ('expired', 'not yet valid'))
        advice = 'renew it' if dated else \
            f'{_label(tls, "tls_ca_file")} must be the CA that signed it'
        return (f'scheduler {address}: its certificate does not verify '
                f'({verify.verify_message}): {advice}')
    why = next((why for marker, why in _CLIENT_REFUSED if marker in text), None)
    if why is not None:
        return (f"scheduler {address} refused this client's certificate ({why}): give "
                f'{_either(tls, ["tls_client_cert", "tls_client_key"])} a certificate signed '
                "by the scheduler's CA and valid now")
    # A scheduler in clear answers a TLS hello with its own bytes, or sends them first.
    if 'WRONG_VERSION_NUMBER' in text or 'cannot convert to SSL' in text:
        return (f'scheduler {address} does not speak TLS: give it as tcp://HOST:PORT, '
                f'without {OPTIONS}')
    seconds = parse_timedelta(dask.config.get(CONNECT_TIMEOUT), default='seconds')
    if str(err).startswith('Timed out trying to connect'):
        last = getattr(chain[-1], 'strerror', None)  # Connection refused, ...
        return (f'scheduler {address}: no answer within {seconds:g} s ({CONNECT_TIMEOUT})'
                f'{": " + last if last else ""}; is the scheduler running at this address?')
    if isinstance(err, TimeoutError):
        return (f'scheduler {address} took the connection but did not answer as a Dask '
                f'scheduler within twice {seconds:g} s ({CONNECT_TIMEOUT}): is this the '
                "scheduler's address?")
    if isinstance(err, OSError) and not address.startswith('tls://'):
        return (f'scheduler {address} hung up (as one that needs TLS does on a client in '
                f'clear): give it as tls://HOST:PORT with {OPTIONS}')
    return f'scheduler {address}: cannot connect: {one_line(err)}'


def _probe(address: str, security) -> None:
    """
    Open and close one connection to the scheduler, Dask's handshake included.

    Dask bounds the connection by its connect timeout, not the handshake
    after it: a peer that accepts and stays silent would hold the client for
    ever. The handshake gets another such timeout (TimeoutError).
    """
    import asyncio
    import dask
    from dask.utils import parse_timedelta
    from distributed.comm import connect
    seconds = parse_timedelta(dask.config.get(CONNECT_TIMEOUT), default='seconds')

    async def once() -> None:
        comm = await asyncio.wait_for(
            connect(address, timeout=seconds, **security.get_connection_args('client')),
            2 * seconds)
        await comm.close()
    asyncio.run(once())


def scheduler_client(address: str, tls: TlsOptions):
    """Connect a Dask client to the scheduler at ``address``; a refusal is one UserError line."""
    from dask.distributed import Client
    security = _security(address, tls)
    try:
        _probe(address, security)
        return Client(address, security=security)
    except (OSError, ValueError) as err:  # refused, timed out, a certificate, not an address
        raise UserError(refusal(address, tls, err)) from None
