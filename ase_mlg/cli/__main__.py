"""``python -m ase_mlg.cli``: the ``ase-mlg`` command."""

import sys

from . import main

sys.exit(main())
