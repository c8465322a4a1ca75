"""`python -m companion.cli ARGS` is `uavsearch ARGS` (the launcher starts its children so)."""

import sys

from companion.cli.entry import main

sys.exit(main())
