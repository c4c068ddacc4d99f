"""TLS credentials of a Dask cluster: a freshly generated certificate and key in a private folder.

A LocalCluster started by :func:`render_service.engine.dask_client` listens on ``tls://127.0.0.1``
with mutual TLS (``distributed.security.Security(require_encryption=True)``): the scheduler, the
workers and the client all present the same self-signed certificate, which is also the only trusted
CA.  Whoever cannot read the key file cannot connect, so cannot run code on the workers.

The folder is created with mode 0700 and the files with mode 0600 (owner only); an existing folder
readable by others is refused rather than trusted.  The key is an ECDSA P-256 key, the certificate
valid from one hour ago for ``days`` days.
"""
from __future__ import annotations

import datetime as dt
import logging
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from board.atomic import atomic_path
from board.errors import InvalidInputError

log = logging.getLogger(__name__)

CERT_NAME = "dask-cert.pem"
KEY_NAME = "dask-key.pem"


@dataclass(frozen=True)
class TlsFiles:
    """Paths of a cluster's credentials: the certificate (also the CA) and its private key (PEM)."""

    cert: Path
    key: Path

    def security(self):
        """The ``distributed.security.Security`` for every role (scheduler, worker, client)."""
        from distributed.security import Security  # noqa: PLC0415 (ground segment only)

        c, k = str(self.cert), str(self.key)
        return Security(require_encryption=True, tls_ca_file=c, tls_client_cert=c, tls_client_key=k,
                        tls_scheduler_cert=c, tls_scheduler_key=k, tls_worker_cert=c, tls_worker_key=k)


def private_dir(path: Path) -> Path:
    """Create ``path`` (mode 0700) or check that an existing one is the user's and closed to others."""
    path = Path(path)
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = path.stat()
    if st.st_uid != os.getuid():
        raise InvalidInputError(f"the credentials folder {path} belongs to another user: remove it or choose "
                                "another data directory")
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        os.chmod(path, 0o700)  # ours: close it (files inside are rewritten below anyway)
    return path


def _write_private(path: Path, data: bytes) -> None:
    with atomic_path(path, suffix=".tmp") as tmp:
        tmp.unlink(missing_ok=True)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)  # private from the first byte
        try:
            os.write(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)


def generate_tls_files(folder: Path, *, days: int = 30, common_name: str = "skyloc-dask") -> TlsFiles:
    """Write a new self-signed certificate and key into ``folder`` (replacing older ones)."""
    from cryptography import x509  # noqa: PLC0415
    from cryptography.hazmat.primitives import hashes, serialization  # noqa: PLC0415
    from cryptography.hazmat.primitives.asymmetric import ec  # noqa: PLC0415
    from cryptography.x509.oid import NameOID  # noqa: PLC0415

    folder = private_dir(folder)
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])
    now = dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(hours=1)).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(key, hashes.SHA256()))
    files = TlsFiles(cert=folder / CERT_NAME, key=folder / KEY_NAME)
    _write_private(files.key, key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                                serialization.NoEncryption()))
    _write_private(files.cert, cert.public_bytes(serialization.Encoding.PEM))
    log.info("generated the Dask TLS credentials in %s", folder)
    return files
