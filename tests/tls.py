"""TLS material for the tests: a throw-away CA and a localhost certificate (tmp dir only)."""

from __future__ import annotations


def make_tls(tmp_path):
    """A throw-away CA and a router certificate for localhost/127.0.0.1 (tmp dir only)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    now = datetime.datetime.now(datetime.UTC)

    def cert(subject, issuer, key, signer, ca: bool, san=None):
        b = (x509.CertificateBuilder()
             .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, subject)]))
             .issuer_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, issuer)]))
             .public_key(key.public_key()).serial_number(x509.random_serial_number())
             .not_valid_before(now - datetime.timedelta(minutes=5))
             .not_valid_after(now + datetime.timedelta(days=1))
             .add_extension(x509.BasicConstraints(ca=ca, path_length=None), critical=True))
        if san:
            b = b.add_extension(x509.SubjectAlternativeName(san), critical=False)
        return b.sign(signer, hashes.SHA256())

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = cert("workcell test CA", "workcell test CA", ca_key, ca_key, True)
    key = ec.generate_private_key(ec.SECP256R1())
    srv = cert("localhost", "workcell test CA", key, ca_key, False,
               [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))])
    files = {"ca": ca.public_bytes(serialization.Encoding.PEM),
             "cert": srv.public_bytes(serialization.Encoding.PEM),
             "key": key.private_bytes(serialization.Encoding.PEM,
                                      serialization.PrivateFormat.PKCS8,
                                      serialization.NoEncryption())}
    paths = {}
    for name, data in files.items():
        paths[name] = tmp_path / f"{name}.pem"
        paths[name].write_bytes(data)
    return paths


def secure_router(tmp_path, config_file, users: dict[str, str], port: int):
    """The shipped router config ``config_file`` (deploy/zenoh/) with the test's TLS material,
    users file and port on 127.0.0.1: everything else (its access control) as shipped."""
    import json

    import zenoh

    tls = make_tls(tmp_path)
    users_file = tmp_path / "zenoh-users.txt"
    users_file.write_text("".join(f"{u}:{p}\n" for u, p in users.items()))
    conf = zenoh.Config.from_file(str(config_file))
    for key, value in {
        "listen/endpoints": [f"tls/127.0.0.1:{port}"],
        "connect/endpoints": [],
        "transport/link/tls/root_ca_certificate": str(tls["ca"]),
        "transport/link/tls/listen_certificate": str(tls["cert"]),
        "transport/link/tls/listen_private_key": str(tls["key"]),
        "transport/auth/usrpwd/dictionary_file": str(users_file),
    }.items():
        conf.insert_json5(key, json.dumps(value))
    return conf, tls
