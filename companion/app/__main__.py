"""`python -m companion.app ARGS` is `uavsearch ARGS` (the launcher starts its children so)."""

import sys

from companion.app.entry import main

sys.exit(main())
