"""tl_bag: maintenance of recorded MCAP bags.

  tl_bag recover IN.mcap OUT.mcap   rewrite a truncated bag (recorder killed, power lost)
                                    into a valid one: every message up to the last complete
                                    chunk; exit 0, and a warning line if IN was cut
  tl_bag info BAG.mcap              messages per topic (from the bag's summary)
"""
from __future__ import annotations

import argparse
import sys

from ..core.bagio import recover_bag, topic_counts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="tl_bag", description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(__doc__.splitlines()[2:]))
    sub = ap.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("recover", help="rewrite a truncated bag into a valid one")
    rec.add_argument("input")
    rec.add_argument("output")
    info = sub.add_parser("info", help="messages per topic")
    info.add_argument("bag")
    args = ap.parse_args(argv)
    try:
        if args.command == "recover":
            counts, problem = recover_bag(args.input, args.output)
            total = sum(counts.values())
            if problem:
                print(f"[tl_bag] warning: {args.input} ends early ({problem}); recovered what came before it",
                      file=sys.stderr)
            print(f"[tl_bag] wrote {args.output}: {total} messages "
                  f"({', '.join(f'{t}={n}' for t, n in sorted(counts.items())) or 'none'})")
        else:
            for topic, n in sorted(topic_counts(args.bag).items()):
                print(f"{topic}\t{n}")
    except OSError as exc:
        print(f"[tl_bag] error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
