"""``fleet keys init``: the identities and the router config of a secured bus."""

from __future__ import annotations

import argparse
from pathlib import Path

from fleet.cli.common import EXIT_OK, SubParsers, add_command, add_config, add_endpoint, load
from fleet.errors import BusError, ConfigError

EPILOG = """\
example:
  fleet keys init configs/warehouse_patrol.yaml out/keys
  fleet sim configs/warehouse_patrol.yaml --secure out/keys
  fleet coordinator configs/warehouse_patrol.yaml --secure out/keys
  fleet agent configs/warehouse_patrol.yaml --robot robot1 --secure out/keys
  fleet status --secure out/keys

Every file is mode 0600 and secret: anyone who can read DIR can act as any identity.
See docs/security.md for what each identity may do.
"""


def add_parser(sub: SubParsers) -> argparse.ArgumentParser:
    """Add ``fleet keys`` (``fleet keys init``) to ``fleet``'s subcommands."""
    p = add_command(
        sub,
        "keys",
        lambda args: args.keys_handler(args),
        help="make the identities of a secured bus (--secure DIR)",
        description="Identities for a secured Zenoh bus: the router checks a user and password per "
        "process and lets each do only what its role needs (docs/security.md).",
    )
    ksub = p.add_subparsers(dest="keys_command", metavar="ACTION", required=True)
    init = ksub.add_parser(
        "init",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        help="write one identity per robot, coordinator, simulator, observer, worker, the router config and the API token",
        description="Write DIR/<identity>.json5 (a Zenoh client config a plain Zenoh session opens as "
        "is) for every robot of CONFIG and for coordinator, simulator, observer and worker (load-test workers); DIR/router.json5 "
        "(credentials + access control) with DIR/router.passwords; DIR/api.token (the HTTP API's token).",
        epilog=EPILOG,
    )
    add_config(init)
    init.add_argument("dir", type=Path, metavar="DIR", help="key directory (created mode 0700)")
    add_endpoint(init)
    init.add_argument("--force", action="store_true", help="replace the keys already in DIR")
    init.add_argument(
        "--tls",
        action="store_true",
        help="also a CA and a certificate per identity in DIR/tls: the bus runs over TLS with client "
        "certificates (mutual TLS) on tls/<host>:<port> (needs the cryptography package)",
    )
    init.set_defaults(keys_handler=handle_init)
    show = ksub.add_parser(
        "show",
        help="what each identity of DIR may do, read back from the router's access control",
        description="List the identities of a key directory, its endpoint, whether it uses TLS, and what "
        "the router lets each identity publish, receive, hold, watch, serve and ask.",
    )
    show.add_argument("dir", type=Path, metavar="DIR", help="key directory (fleet keys init)")
    show.set_defaults(keys_handler=handle_show)
    return p


def handle_show(args: argparse.Namespace) -> int:
    """Print the identities of ``args.dir`` and their rights."""
    import json

    from fleet.bus.access import VERBS, describe
    from fleet.bus.keyring import Keyring

    ring = Keyring(args.dir)
    endpoints: list[str] = json.loads(ring.router_config().get_json("listen/endpoints"))
    rights = describe(ring.access())
    tls = "mutual TLS" if ring.tls else "no TLS (credentials in the clear: loopback or a trusted network)"
    print(f"keys: {ring.dir}, router on {', '.join(endpoints)}, {tls}, {len(rights)} identities")
    verbs = list(dict.fromkeys(VERBS.values()))
    for identity, allowed in rights.items():
        print(f"{identity}:")
        for verb in verbs:
            if allowed.get(verb):
                print(f"  {verb:<9} {', '.join(allowed[verb])}")
        if not any(allowed.get(v) for v in ("publishes", "holds", "serves")):
            print("  (read only)")
    return EXIT_OK


def handle_init(args: argparse.Namespace) -> int:
    """Write the key directory; list what was written."""
    from fleet.bus.certificates import tls_endpoint
    from fleet.bus.keyring import init_keyring, keyring_files

    config = load(args)
    robots = [r.name for r in config.robots]
    endpoint = args.endpoint or config.endpoint
    if args.tls:
        try:
            endpoint = tls_endpoint(endpoint)
        except ValueError as e:
            raise BusError(f"--endpoint: {e}") from None
    try:
        ring = init_keyring(args.dir, robots, endpoint, force=args.force, tls=args.tls)
    except ValueError as e:
        raise ConfigError(str(config.path), "robots", str(e)) from None
    files = keyring_files(robots, args.tls)
    print(f"keys: {len(files)} files in {ring.dir} (mode 0600) for {endpoint}")
    if args.tls:
        print("  TLS: tls/ca.pem and a certificate per identity (mutual TLS); the CA's key is not kept")
    print(f"  identities: {', '.join(robots)}, coordinator, simulator, observer, worker")
    print("  router: router.json5 + router.passwords; HTTP API token: api.token")
    print(f"  use: fleet run {config.path} --secure {args.dir}   (see docs/security.md)")
    return EXIT_OK
