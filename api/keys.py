"""``python -m api.keys new --id ID --owner WHO --scopes score,plan``: a new API key.

Prints the key (give it to its holder; it is shown once and stored nowhere) on stdout and, on
stderr, the entry to add to the server's keys file (``EXCITE_API_KEYS_FILE``), which holds
only the key's SHA-256. ``python -m api.keys hash`` reads a key on stdin and prints its hash.
"""

from __future__ import annotations

import argparse
import json
import sys

from .auth import SCOPES, hash_key, new_key


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m api.keys", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    new = sub.add_parser("new", help="make a key and print its keys-file entry")
    new.add_argument("--id", required=True, help="the key's name in logs and job records")
    new.add_argument("--owner", required=True, help="who holds it")
    new.add_argument("--scopes", required=True, help=f"comma-separated: {', '.join(SCOPES)}")
    sub.add_parser("hash", help="the SHA-256 of a key read on stdin")
    args = ap.parse_args(argv)
    if args.command == "hash":
        print(hash_key(sys.stdin.readline().strip()))
        return 0
    scopes = [s.strip() for s in args.scopes.split(",") if s.strip()]
    bad = [s for s in scopes if s not in SCOPES]
    if bad or not scopes:
        ap.error(f"--scopes: {bad[0] if bad else 'none'} is not one of {', '.join(SCOPES)}")
    key = new_key()
    entry = {"id": args.id, "owner": args.owner, "scopes": scopes, "sha256": hash_key(key)}
    print(key)
    print("add to the keys file (under keys:):\n  - " + json.dumps(entry), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
