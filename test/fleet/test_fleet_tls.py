"""
``mlx-tempcomp fleet`` against a Dask scheduler that requires TLS, over loopback.

The test makes its own certificate authority and certificates (``cryptography``):
the cluster's (scheduler, worker and client share one, as Dask's docs allow), one
expired, and one signed by another CA. A real ``dask scheduler`` and ``dask
worker`` run with ``--tls-*`` and ``distributed.comm.require-encryption``; the
fleet runs its units there with the certificates given as options or through
Dask's configuration (environment variables), and every other way in is
refused with one line and exit code 2: no certificates, a certificate the
scheduler refuses or does not verify, a file that is missing or not PEM, a
scheduler in clear, nothing listening, a peer that never answers.
"""

import datetime
import ipaddress
import json
import os
from pathlib import Path
import socket
import subprocess
import sys

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID
import dask
from dask.distributed import Client, Security
from fleet_runs import DASK, run_cli, wait_for, write_record
from mlx_tempcomp.fleet.run import connect
import pytest

UNITS = ('t1', 't2', 't3')
# The units' plots are most of their time and nothing the connection changes.
NO_PLOTS = '--options=--no-plots'
# What the fleet's subprocesses and the Dask processes get: a generous connect timeout.
TIMEOUT_S = 300
NEEDS_TLS = ('error: scheduler {address} needs TLS: give --tls-ca-file, --tls-cert and '
             '--tls-key (or distributed.comm.tls.ca-file, distributed.comm.tls.client.cert and '
             "distributed.comm.tls.client.key in Dask's configuration)\n")
REFUSED = "error: scheduler {address} refused this client's certificate ("
REFUSED_END = ('): give --tls-cert and --tls-key (or distributed.comm.tls.client.cert and '
               "distributed.comm.tls.client.key in Dask's configuration) a certificate signed "
               "by the scheduler's CA and valid now\n")


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _certificate(subject: str, key, issuer, issuer_key, *, days: tuple, ca: bool):
    """Give a certificate of ``key`` signed by ``issuer_key``, valid from days[0] to days[1]."""
    now = datetime.datetime.now(datetime.timezone.utc)
    builder = (x509.CertificateBuilder().subject_name(_name(subject)).issuer_name(issuer)
               .public_key(key.public_key()).serial_number(x509.random_serial_number())
               .not_valid_before(now + datetime.timedelta(days=days[0]))
               .not_valid_after(now + datetime.timedelta(days=days[1]))
               .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
    if not ca:
        builder = builder.add_extension(x509.SubjectAlternativeName(
            [x509.IPAddress(ipaddress.ip_address('127.0.0.1'))]), critical=False)
    return builder.sign(issuer_key, hashes.SHA256())


def _authority(folder: Path, name: str):
    """Write a self-signed CA certificate ``name``.pem; give (its key, its name)."""
    key = ec.generate_private_key(ec.SECP256R1())
    cert = _certificate(name, key, _name(name), key, days=(-1, 30), ca=True)
    (folder / f'{name}.pem').write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key, cert.subject


def _leaf(folder: Path, name: str, authority, days=(-1, 30)) -> None:
    """Write ``name``.crt and ``name``.key, a certificate signed by ``authority``."""
    key = ec.generate_private_key(ec.SECP256R1())
    cert = _certificate(name, key, authority[1], authority[0], days=days, ca=False)
    (folder / f'{name}.crt').write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    (folder / f'{name}.key').write_bytes(key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption()))


@pytest.fixture(scope='module')
def certificates(tmp_path_factory) -> Path:
    """Write ca.pem with node and expired signed by it, other-ca.pem with stranger."""
    folder = tmp_path_factory.mktemp('tls')
    authority = _authority(folder, 'ca')
    _leaf(folder, 'node', authority)
    _leaf(folder, 'expired', authority, days=(-3, -1))
    _leaf(folder, 'stranger', _authority(folder, 'other-ca'))
    return folder


def tls_options(folder: Path, name: str = 'node', ca: str = 'ca') -> list:
    """Give the fleet command's options of certificate ``name`` and CA ``ca``."""
    return ['--tls-ca-file', folder / f'{ca}.pem', '--tls-cert', folder / f'{name}.crt',
            '--tls-key', folder / f'{name}.key']


@pytest.fixture(scope='module')
def manifest(tmp_path_factory) -> Path:
    """Write a record per unit (test_fleet's chamber records) and their manifest."""
    folder = tmp_path_factory.mktemp('tls-records')
    for seed, unit in enumerate(UNITS):
        write_record(folder / f'{unit}.csv', seed)
    path = folder / 'units.csv'
    path.write_text('unit,path\n' + ''.join(f'{u},{u}.csv\n' for u in UNITS), encoding='utf-8')
    return path


@pytest.fixture(scope='module')
def tls_scheduler(certificates, tmp_path_factory) -> str:
    """Start a dask scheduler and one worker that require TLS on 127.0.0.1; give the address."""
    folder = tmp_path_factory.mktemp('tls-cluster')
    scheduler_file = folder / 'scheduler.json'
    tls = ['--tls-ca-file', certificates / 'ca.pem', '--tls-cert', certificates / 'node.crt',
           '--tls-key', certificates / 'node.key']
    env = {**os.environ, 'DASK_DISTRIBUTED__COMM__REQUIRE_ENCRYPTION': 'True'}
    started = []
    try:
        started.append(subprocess.Popen(
            [DASK, 'scheduler', '--protocol', 'tls', '--host', '127.0.0.1', '--port', '0',
             '--no-dashboard', '--scheduler-file', scheduler_file, *tls], env=env,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        wait_for(scheduler_file.exists, 120.0, 'the scheduler file')
        address = json.loads(scheduler_file.read_text())['address']
        assert address.startswith('tls://127.0.0.1:')
        started.append(subprocess.Popen(
            [DASK, 'worker', address, '--nthreads', '1', '--no-nanny', '--no-dashboard', *tls],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        security = Security(tls_ca_file=str(certificates / 'ca.pem'),
                            tls_client_cert=str(certificates / 'node.crt'),
                            tls_client_key=str(certificates / 'node.key'),
                            require_encryption=True)
        with Client(address, security=security, timeout=TIMEOUT_S) as client:
            client.wait_for_workers(1, timeout=TIMEOUT_S)
        yield address
    finally:
        for process in reversed(started):
            if process.poll() is None:
                process.kill()
            process.wait(30)


def fleet(manifest: Path, out: Path, *options, env=None) -> tuple:
    """Run ``mlx-tempcomp fleet diagnose`` as a process; give (exit code, stdout, stderr)."""
    done = subprocess.run(
        [sys.executable, '-m', 'mlx_tempcomp.cli', 'fleet', 'diagnose', '--manifest', manifest,
         '--out', out, *[str(option) for option in options]], capture_output=True, text=True,
        env={**os.environ, **(env or {})}, timeout=TIMEOUT_S)
    return done.returncode, done.stdout, done.stderr


def all_done(code: int, stdout: str, out: Path) -> None:
    """Check every unit ran and is stored as finished."""
    assert code == 0, stdout
    assert f'{len(UNITS)} units: {len(UNITS)} done, 0 finished before (skipped), 0 failed' \
        in stdout
    for unit in UNITS:
        entry = json.loads((out / 'units' / unit / 'unit.json').read_text())
        assert entry['status'] == 'ok' and (out / 'units' / unit / 'params.yaml').exists()


@pytest.mark.slow
def test_the_certificates_as_options_run_every_unit(manifest, certificates, tls_scheduler,
                                                    tmp_path):
    out = tmp_path / 'out'
    code, stdout, stderr = run_cli(['fleet', 'diagnose', '--manifest', manifest, '--out', out,
                                    '--scheduler', tls_scheduler, *tls_options(certificates),
                                    NO_PLOTS])
    all_done(code, stdout, out)


@pytest.mark.slow
def test_the_certificates_in_dasks_configuration_run_every_unit(manifest, certificates,
                                                                tls_scheduler, tmp_path):
    out = tmp_path / 'out'
    code, stdout, stderr = fleet(manifest, out, '--scheduler', tls_scheduler, NO_PLOTS, env={
        'DASK_DISTRIBUTED__COMM__TLS__CA_FILE': str(certificates / 'ca.pem'),
        'DASK_DISTRIBUTED__COMM__TLS__CLIENT__CERT': str(certificates / 'node.crt'),
        'DASK_DISTRIBUTED__COMM__TLS__CLIENT__KEY': str(certificates / 'node.key')})
    all_done(code, stdout, out)
    assert 'Traceback' not in stderr


@pytest.mark.slow
def test_no_certificates_or_a_stranger_is_one_line_and_exit_2(manifest, certificates,
                                                              tls_scheduler, tmp_path):
    """As a user runs it: the whole of stderr is the one line; nothing is written."""
    out = tmp_path / 'out'
    assert fleet(manifest, out, '--scheduler', tls_scheduler) == \
        (2, '', NEEDS_TLS.format(address=tls_scheduler))
    code, stdout, stderr = fleet(manifest, out, '--scheduler', tls_scheduler,
                                 *tls_options(certificates, 'stranger'))
    assert (code, stdout) == (2, '')
    # The scheduler says why in its TLS alert (unknown CA) or just hangs up: either names it.
    assert stderr.startswith(REFUSED.format(address=tls_scheduler)), stderr
    assert stderr.endswith(REFUSED_END) and stderr.count('\n') == 1, stderr
    assert not out.exists()


def refusal_line(argv: list, tmp_path: Path) -> str:
    """Run the fleet in this process; check it is refused (exit 2) with one line; give it."""
    out = tmp_path / 'out'
    code, stdout, stderr = run_cli(['fleet', 'diagnose', '--out', out, *argv])
    assert (code, stdout, stderr.count('\n')) == (2, '', 1), (code, stdout, stderr)
    assert not out.exists()
    return stderr


@pytest.mark.slow
def test_every_wrong_certificate_is_refused_in_one_line(manifest, certificates, tls_scheduler,
                                                        tmp_path):
    address = tls_scheduler
    run = ['--manifest', manifest, '--scheduler', address]
    options = tls_options(certificates)
    assert refusal_line(run + options[:2], tmp_path) == \
        f'error: scheduler {address} needs TLS: give --tls-cert (or ' \
        "distributed.comm.tls.client.cert in Dask's configuration) too\n"
    line = refusal_line(run + tls_options(certificates, 'expired'), tmp_path)
    assert line.startswith(REFUSED.format(address=address)) and line.endswith(REFUSED_END)
    line = refusal_line(run + tls_options(certificates, ca='other-ca'), tmp_path)
    assert line.startswith(f'error: scheduler {address}: its certificate does not verify (')
    assert line.endswith('): --tls-ca-file must be the CA that signed it\n')
    with dask.config.set({'distributed.comm.tls.ca-file': str(certificates / 'other-ca.pem')}):
        line = refusal_line(run + options[2:], tmp_path)
    assert line.endswith('): distributed.comm.tls.ca-file must be the CA that signed it\n')
    missing = certificates / 'missing.crt'
    assert refusal_line(run + options[:2] + ['--tls-cert', missing] + options[4:], tmp_path) == \
        f'error: scheduler {address}: --tls-cert {missing}: No such file or directory\n'
    assert refusal_line(run + ['--tls-ca-file', manifest] + options[2:], tmp_path) == \
        f'error: scheduler {address}: the TLS files do not load (the CA file holds no ' \
        f'certificate): --tls-ca-file {manifest}, --tls-cert {options[3]}, --tls-key ' \
        f'{options[5]}\n'
    line = refusal_line(run + options[:4] + ['--tls-key', certificates / 'stranger.key'],
                        tmp_path)
    assert line.startswith(f'error: scheduler {address}: the TLS files do not load (the key '
                           "is not the certificate's): ")
    clear = address.replace('tls://', 'tcp://')
    assert refusal_line(['--manifest', manifest, '--scheduler', clear], tmp_path) == \
        f'error: scheduler {clear} hung up (as one that needs TLS does on a client in clear): ' \
        'give it as tls://HOST:PORT with --tls-ca-file, --tls-cert and --tls-key\n'


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


def test_an_unreachable_scheduler_is_one_line_within_the_connect_timeout(
        manifest, certificates, tmp_path):
    """Nothing listens there: Dask tries for distributed.comm.timeouts.connect, then one line."""
    for address, options in ((f'tls://127.0.0.1:{_free_port()}', tls_options(certificates)),
                             (f'tcp://127.0.0.1:{_free_port()}', [])):
        with dask.config.set({'distributed.comm.timeouts.connect': '1s'}):
            line = refusal_line(['--manifest', manifest, '--scheduler', address, *options],
                                tmp_path)
        # Dask keeps its last try's error: refused, or its own timeout when time ran out.
        assert line in [f'error: scheduler {address}: no answer within 1 s '
                        f'(distributed.comm.timeouts.connect){refused}; is the scheduler '
                        'running at this address?\n' for refused in (': Connection refused', '')]


def test_a_peer_that_never_answers_is_one_line_not_a_hang(manifest, tmp_path):
    """It takes the connection and says nothing: Dask's handshake is bounded too."""
    with socket.socket() as mute:
        mute.bind(('127.0.0.1', 0))
        mute.listen()
        address = f'tcp://127.0.0.1:{mute.getsockname()[1]}'
        with dask.config.set({'distributed.comm.timeouts.connect': '1s'}):
            line = refusal_line(['--manifest', manifest, '--scheduler', address], tmp_path)
    assert line == f'error: scheduler {address} took the connection but did not answer as a ' \
        'Dask scheduler within twice 1 s (distributed.comm.timeouts.connect): is this the ' \
        "scheduler's address?\n"


def test_tls_where_it_cannot_apply_is_refused_before_connecting(manifest, certificates,
                                                                tmp_path, monkeypatch):
    monkeypatch.delenv('DASK_SCHEDULER_ADDRESS', raising=False)
    options = ['--manifest', manifest, *tls_options(certificates)]
    assert refusal_line(options, tmp_path) == \
        'error: --tls-ca-file, --tls-cert and --tls-key are the certificates of a tls:// ' \
        'scheduler: give --scheduler tls://HOST:PORT too (without it the fleet runs on a ' \
        'local cluster, in clear on 127.0.0.1)\n'
    assert refusal_line(options + ['--scheduler', 'tcp://127.0.0.1:8786'], tmp_path) == \
        'error: scheduler tcp://127.0.0.1:8786: --tls-ca-file, --tls-cert and --tls-key are ' \
        'for a tls:// scheduler; give it as tls://HOST:PORT\n'
    with dask.config.set({'distributed.comm.require-encryption': True}):
        assert refusal_line(['--manifest', manifest], tmp_path) == \
            "error: Dask's configuration requires encryption " \
            '(distributed.comm.require-encryption) and the local cluster runs in clear on ' \
            '127.0.0.1: give --scheduler tls://HOST:PORT, or set ' \
            'distributed.comm.require-encryption to False\n'
        assert refusal_line(['--manifest', manifest, '--scheduler', '127.0.0.1:8786'],
                            tmp_path) == \
            "error: scheduler 127.0.0.1:8786: Dask's configuration requires encryption " \
            '(distributed.comm.require-encryption): give it as tls://HOST:PORT\n'


def test_a_local_cluster_ignores_the_configured_certificates_and_is_not_tls(
        manifest, certificates, tmp_path, monkeypatch):
    """Dask's configuration names the client's certificates: the local cluster runs in clear."""
    monkeypatch.delenv('DASK_SCHEDULER_ADDRESS', raising=False)
    configured = {'distributed.comm.tls.ca-file': str(certificates / 'ca.pem'),
                  'distributed.comm.tls.client.cert': str(certificates / 'node.crt'),
                  'distributed.comm.tls.client.key': str(certificates / 'node.key')}
    with dask.config.set(configured):
        client, cluster = connect(None, 1)
    try:
        address = cluster.scheduler_address
        assert address.startswith('tcp://127.0.0.1:')
        assert client.submit(sum, [1, 2]).result() == 3
        tls = address.replace('tcp://', 'tls://')
        assert refusal_line(['--manifest', manifest, '--scheduler', tls,
                             *tls_options(certificates)], tmp_path) == \
            f'error: scheduler {tls} does not speak TLS: give it as tcp://HOST:PORT, without ' \
            '--tls-ca-file, --tls-cert and --tls-key\n'
    finally:
        client.close()
        cluster.close()
