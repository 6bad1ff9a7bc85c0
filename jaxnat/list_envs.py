"""`jaxnat envs [FAMILY ...]`: the registered env ids, by family (Classify, Localize, MuJoCo,
PixelMuJoCo, NaturalAtari), each family on one line; with families named, only theirs."""

from __future__ import annotations

import argparse
import sys

PROG = "jaxnat envs"


def families(ids) -> dict[str, list[str]]:
    """`{family: its ids}` in the registry's order (an id's family is the part before `/`)."""
    grouped: dict[str, list[str]] = {}
    for env_id in ids:
        grouped.setdefault(env_id.partition("/")[0], []).append(env_id)
    return grouped


def main(argv=None) -> int:
    """List the ids; an unknown family is a one-line error naming the known ones (exit 2)."""
    from jaxnat.registration import close_matches, registered_envs

    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0].split(": ", 1)[1])
    parser.add_argument("family", nargs="*", help="only these families (e.g. Classify PixelMuJoCo)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    grouped = families(registered_envs())
    unknown = [name for name in args.family if name not in grouped]
    if unknown:
        close = close_matches(unknown[0], grouped)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        print(f"{PROG}: error: unknown family {unknown[0]!r}{hint}; families: {', '.join(grouped)}", file=sys.stderr)
        return 2
    for family, ids in grouped.items():
        if not args.family or family in args.family:
            print(f"{family} ({len(ids)}): {' '.join(env_id.partition('/')[2] for env_id in ids)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
