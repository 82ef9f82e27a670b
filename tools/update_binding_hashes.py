#!/usr/bin/env python3
"""Keep the hand-written pybind11 bindings in step with their headers.

GNU Radio's cmake macro GR_PYBIND_MAKE_OOT compares the MD5 of each header with the
BINDTOOL_HEADER_FILE_HASH(...) line of its *_python.cc and stops with "bindings are out of
sync" when they differ. gr_modtool bind cannot regenerate our bindings (castxml fails on
gcc-12 headers), so the bindings are written by hand; after changing a header, update the
binding by hand, then run this script to record the new hash.

    tools/update_binding_hashes.py          # rewrite the hashes
    tools/update_binding_hashes.py --check  # exit 1 and name the files that are stale
"""
import argparse
import hashlib
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
BINDINGS = ROOT / "python" / "thrumapper" / "bindings"
HEADERS = ROOT / "include" / "gnuradio" / "thrumapper"
HEADER_RE = re.compile(r"BINDTOOL_HEADER_FILE\(([^)]*)\)")
HASH_RE = re.compile(r"BINDTOOL_HEADER_FILE_HASH\(([^)]*)\)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="only check; exit 1 if any hash is stale")
    args = parser.parse_args()
    stale = []
    for binding in sorted(BINDINGS.glob("*_python.cc")):
        text = binding.read_text()
        header_match = HEADER_RE.search(text)
        if not header_match:
            continue
        header = HEADERS / header_match.group(1)
        if not header.exists():
            print(f"{binding.name}: header {header} does not exist", file=sys.stderr)
            return 2
        digest = hashlib.md5(header.read_bytes()).hexdigest()
        hash_match = HASH_RE.search(text)
        if hash_match and hash_match.group(1) == digest:
            continue
        stale.append(binding.name)
        if not args.check:
            text = HASH_RE.sub(f"BINDTOOL_HEADER_FILE_HASH({digest})", text)
            binding.write_text(text)
    if args.check and stale:
        print("bindings out of sync with their headers: " + ", ".join(stale) +
              "\n(update the binding, then run tools/update_binding_hashes.py)", file=sys.stderr)
        return 1
    for name in stale:
        print(f"updated {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
