"""Fail unless every package pinned in a constraints file is installed at
exactly that version (a pip constraints file only applies to packages that
something asked for; this checks none was left out or resolved otherwise)."""

import sys
from importlib.metadata import PackageNotFoundError, version


def main(path):
    bad = []
    for line in open(path):
        line = line.split("#")[0].strip()
        if not line:
            continue
        name, want = line.split("==")
        try:
            have = version(name)
        except PackageNotFoundError:
            have = "not installed"
        if have != want:
            bad.append(f"{name}: pinned {want}, installed {have}")
        else:
            print(f"{name}=={have}")
    if bad:
        sys.exit("oldest versions not installed: " + "; ".join(bad))


if __name__ == "__main__":
    main(sys.argv[1])
