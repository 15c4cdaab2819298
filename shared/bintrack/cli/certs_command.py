"""``bintrack certs --out DIR [--roles ROLE,…] [--days N] [--ca DIR]``.

Makes the certificates of the secure profile (``deploy/secure/``) with the ``cryptography``
package: a certificate authority (``ca.pem``, ``ca-key.pem``) and, per role, ``<role>.pem`` +
``<role>-key.pem`` signed by it, whose common name is the role (the router's access control
matches it), plus the router's own (``router``, for ``localhost``/127.0.0.1, the compose
host name ``router`` and the addresses of ``up --regions``' region routers, 127.0.0.2 …
127.0.0.251; the region routers show it to each other too). ``merge`` is the role of the
regions' merge service. Keys are EC P-256, written with mode 0600 and never printed. With
``--ca DIR`` an existing CA signs (to rotate one role's certificate, see the README).
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from bintrack.argtypes import output_folder
from bintrack.errors import CommandError
from bintrack.live.stack import MAX_REGIONS, region_address

ROLES = ("router", "sensor_agent", "peer_agent", "basestation", "replay", "recorder", "viewer", "merge")
ROUTER_NAMES = ("localhost", "router")
# the router certificate's addresses: the hub's and those of `up --regions`' region routers
ROUTER_ADDRESSES = ("127.0.0.1", *(region_address(i) for i in range(MAX_REGIONS)))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="folder to write the certificates into")
    parser.add_argument("--roles", default=",".join(ROLES), metavar="ROLE,…",
                        help="roles to make a certificate for (default: %(default)s); any name is a role "
                        "(e.g. sensor_agent-north for a second sensor agent)")
    parser.add_argument("--days", type=int, default=365, help="validity of the certificates, days (default: %(default)s)")
    parser.add_argument("--ca", metavar="DIR", help="sign with the CA in DIR (ca.pem, ca-key.pem) instead of a new one")
    parser.add_argument("--router-name", action="append", default=[], metavar="HOST",
                        help="a further host name or IP address the router certificate names, repeatable: where "
                        "the routers of a mesh on several machines listen (e.g. router-b, 10.0.0.2)")


def _write(path: Path, data: bytes, private: bool) -> None:
    """Write ``data``; a private key is created 0600 from the start (never world-readable)."""
    if path.exists():
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as handle:
        handle.write(data)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "bintrack"),
                      x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def make_ca(days: int) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A self-signed CA certificate valid ``days`` days, and its key."""
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(_name("bintrack CA")).issuer_name(_name("bintrack CA"))
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                         content_commitment=False, key_encipherment=False, data_encipherment=False,
                                         key_agreement=False, encipher_only=False, decipher_only=False), critical=True)
            .sign(key, hashes.SHA256()))
    return cert, key


def host_name(value: str) -> x509.GeneralName:
    """``value`` as a subject alternative name: an IP address, else a DNS name; raises
    CommandError for neither."""
    try:
        return x509.IPAddress(ipaddress.ip_address(value))
    except ValueError:
        pass
    labels = value.rstrip(".").split(".")
    if not value or len(value) > 253 or not all(label and len(label) <= 63 and label.replace("-", "").isalnum()
                                                and not label.startswith("-") for label in labels):
        raise CommandError(f"--router-name {value!r}: not a host name or an IP address")
    return x509.DNSName(value)


def make_leaf(role: str, ca: x509.Certificate, ca_key: ec.EllipticCurvePrivateKey,
              days: int, router_names: tuple[str, ...] = ()) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
    """A certificate with common name ``role`` signed by ``ca``, for client and server use; its
    subject alternative names are the router's host names and 127.0.0.1 (the ``router`` role's
    also the region routers' addresses, :data:`ROUTER_ADDRESSES`, and ``router_names``)."""
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    addresses = ROUTER_ADDRESSES if role == "router" else ("127.0.0.1",)
    names = [x509.DNSName(n) for n in ROUTER_NAMES] + [x509.IPAddress(ipaddress.ip_address(a)) for a in addresses]
    if role == "router":
        names += [n for n in map(host_name, router_names) if n not in names]
    cert = (x509.CertificateBuilder().subject_name(_name(role)).issuer_name(ca.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .sign(ca_key, hashes.SHA256()))
    return cert, key


def make_certs(out: Path, roles: list[str], days: int = 365, ca_dir: Path | None = None,
               router_names: tuple[str, ...] = ()) -> list[Path]:
    """Write the CA (unless ``ca_dir`` gives one) and each role's certificate and key into
    ``out`` (the router's also naming ``router_names``); returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    pem = serialization.Encoding.PEM
    if ca_dir is None:
        ca, ca_key = make_ca(days)
        _write(out / "ca.pem", ca.public_bytes(pem), private=False)
        _write(out / "ca-key.pem", _key_pem(ca_key), private=True)
        written += [out / "ca.pem", out / "ca-key.pem"]
    else:
        try:
            ca = x509.load_pem_x509_certificate((ca_dir / "ca.pem").read_bytes())
            ca_key = serialization.load_pem_private_key((ca_dir / "ca-key.pem").read_bytes(), password=None)
        except (OSError, ValueError) as exc:
            raise CommandError(f"--ca {ca_dir}: cannot read ca.pem and ca-key.pem ({exc})") from None
        if ca_dir.resolve() != out.resolve():
            _write(out / "ca.pem", ca.public_bytes(pem), private=False)
            written.append(out / "ca.pem")
    for role in roles:
        cert, key = make_leaf(role, ca, ca_key, days, router_names)
        _write(out / f"{role}.pem", cert.public_bytes(pem), private=False)
        _write(out / f"{role}-key.pem", _key_pem(key), private=True)
        written += [out / f"{role}.pem", out / f"{role}-key.pem"]
    return written


def run(args: argparse.Namespace) -> int:
    roles = [r.strip() for r in args.roles.split(",") if r.strip()]
    bad = [r for r in roles if not r.replace("_", "").replace("-", "").isalnum()]
    if not roles or bad:
        raise CommandError(f"--roles: role names are letters, digits, - and _; got {args.roles!r}")
    if args.days < 1:
        raise CommandError(f"--days must be at least 1, got {args.days}")
    router_names = tuple(args.router_name)
    for name in router_names:
        host_name(name)  # refused before anything is written
    if args.ca and not (Path(args.ca) / "ca.pem").is_file():
        raise CommandError(f"--ca {args.ca}: no ca.pem there (make one with `bintrack certs --out DIR`)")
    output_folder(Path(args.out))
    try:
        os.chmod(args.out, 0o700)  # it holds private keys: whatever the umask
    except OSError as exc:
        raise CommandError(f"cannot make {args.out} private (chmod 700): {exc.strerror or exc}") from None
    written = make_certs(Path(args.out), roles, args.days, Path(args.ca) if args.ca else None, router_names)
    print(f"certs: wrote {len(written)} files into {args.out} (keys mode 0600): {', '.join(p.name for p in written)}")
    return 0
