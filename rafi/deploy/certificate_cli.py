"""Create the client certificate and private key of `rafi deploy` (OPC UA security).

Writes a self-signed application instance certificate (RSA 2048, SHA-256; the extensions
OPC UA asks for, as asyncua's own cert_gen makes them: the application URI and the host name
as subjectAltName, key usages, clientAuth) and its private key (PEM, unencrypted, mode 600),
then prints the certificate's SHA-256 fingerprint and the lines for config.yaml. The
certificate then goes into the server's list of trusted clients (SINUMERIK: its OPC UA
certificate store, or accept it once on the HMI).

The certificate is written as DER unless its name ends in .pem; the key as PEM unless its name
ends in .der. Neither is overwritten without --force; the key is refused inside a git
repository (keep it outside the project, e.g. /etc/rafi/pki).

The openssl route gives an equivalent pair (docs/deploy.md, Security):

  openssl req -x509 -newkey rsa:2048 -nodes -sha256 -days 730 \\
    -keyout rafi.key -out rafi.pem -subj "/CN=rafi deploy" \\
    -addext "subjectAltName=URI:urn:HOST:rafi:deploy,DNS:HOST" \\
    -addext "keyUsage=critical,digitalSignature,nonRepudiation,keyEncipherment,dataEncipherment" \\
    -addext "extendedKeyUsage=clientAuth"
  chmod 600 rafi.key

Exit status: 0 written; 64 a file exists (without --force), the key would land in a git
repository, or a file cannot be written.
"""

from __future__ import annotations

import datetime
import os
import socket
from pathlib import Path

from rafi.errors import RafiUserError, short_path

__all__ = ["add_arguments", "default_uri", "run", "write_client_certificate"]


def default_uri(host: str | None = None) -> str:
    """The client's application URI by default: ``urn:<host>:rafi:deploy``."""
    return f"urn:{host or socket.gethostname()}:rafi:deploy"


def add_arguments(parser) -> None:
    parser.add_argument("--certificate", required=True, help="the certificate to write (DER; PEM if *.pem)")
    parser.add_argument("--key", required=True, help="the private key to write (PEM; DER if *.der; mode 600)")
    parser.add_argument("--uri", help="the client's application URI (default: urn:<host name>:rafi:deploy)")
    parser.add_argument("--name", default="rafi deploy", help="the certificate's common name (CN)")
    parser.add_argument("--host", help="the host name in the certificate (default: this computer's)")
    parser.add_argument("--days", type=int, default=730, help="valid for this many days (default 730)")
    parser.add_argument("--force", action="store_true", help="overwrite existing files")


def _write(path: Path, data: bytes, mode: int, force: bool) -> None:
    """Write ``data`` to ``path`` created with ``mode`` (never briefly more open), replacing an
    existing file only with ``force``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        if force:
            os.replace(temporary, path)
        else:
            os.link(temporary, path)  # fails if path exists, unlike a rename
    finally:
        temporary.unlink(missing_ok=True)


def write_client_certificate(
    certificate: Path, key: Path, *, uri: str, name: str, host: str, days: int, force: bool = False
) -> bytes:
    """Write a self-signed OPC UA client certificate and its key; the certificate's DER.

    Raises
    ------
    RafiUserError
        A file exists (without ``force``), the key would be inside a git repository, or a file
        cannot be written.
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    from rafi.deploy.opcua_credentials import repository_root

    if days < 1:
        raise RafiUserError(f"--days {days}: expected 1 or more")
    for path in (certificate, key):
        if path.exists() and not force:
            raise RafiUserError(f"{short_path(path)} exists: refused (--force replaces it)")
    repo = repository_root(key.parent.resolve())
    if repo is not None:
        raise RafiUserError(
            f"--key {short_path(key)} lies inside the git repository {short_path(repo)}; keep the private "
            "key outside (e.g. /etc/rafi/pki/rafi.key)"
        )
    private = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)])
    now = datetime.datetime.now(datetime.UTC)
    names = [x509.UniformResourceIdentifier(uri), x509.DNSName(host)]
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(private.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=1))  # a server's clock a little behind
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.SubjectAlternativeName(names), False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(private.public_key()), False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), False)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True, content_commitment=True, key_encipherment=True,
                data_encipherment=True, key_agreement=False, key_cert_sign=True, crl_sign=False,
                encipher_only=False, decipher_only=False,
            ),
            True,
        )
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]), False)
        .sign(private, hashes.SHA256())
    )  # fmt: skip
    enc = serialization.Encoding
    der = cert.public_bytes(enc.DER)
    cert_bytes = cert.public_bytes(enc.PEM) if certificate.suffix.lower() == ".pem" else der
    key_bytes = private.private_bytes(
        enc.DER if key.suffix.lower() == ".der" else enc.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    try:
        _write(key, key_bytes, 0o600, force)
        _write(certificate, cert_bytes, 0o644, force)
    except OSError as exc:
        raise RafiUserError(f"cannot write {short_path(exc.filename or key)}: {exc.strerror}") from None
    return der


def run(args) -> int:
    from rafi.deploy.opcua_security import fingerprint

    host = args.host or socket.gethostname()
    uri = args.uri or default_uri(host)
    certificate, key = Path(args.certificate).expanduser().absolute(), Path(args.key).expanduser().absolute()
    der = write_client_certificate(
        certificate, key, uri=uri, name=args.name, host=host, days=args.days, force=args.force
    )
    print(f"rafi certificate: wrote {certificate} (application URI {uri}, {args.days} days)")
    print(f"rafi certificate: wrote {key} (the private key, mode 600)")
    print(f"SHA-256 fingerprint: {fingerprint(der)}")
    print("Have the server trust this certificate, then in config.yaml, machines.<machine>.deploy.opcua:")
    print("  security_policy: Basic256Sha256        # or Aes128_Sha256_RsaOaep")
    print("  security_mode: SignAndEncrypt")
    print(f"  certificate: {certificate}")
    print(f"  private_key: {key}")
    print("  server_fingerprint: <SHA-256 of the server's certificate>   # or server_certificate / trust_dir")
    return 0
